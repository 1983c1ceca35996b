"""Benchmark: load and preprocess one million rows of roller speeds (CSV and Parquet).

Run: ``python benchmarks/bench_data.py [--rows 1000000] [--repeat 3]``. Writes a synthetic
recording (100 Hz, four rollers, 0.5 % missing samples, 0.1 % spikes) to a temporary folder,
times ``read_measurements`` and ``preprocess`` (best of ``--repeat``), prints a table and
writes ``benchmarks/results/data.json``: a list of ``{figure, value, unit, machine, date}``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table

from drafttwin._io import write_text_atomic
from drafttwin.data import MeasurementSeries, preprocess, read_measurements, write_measurements

RESULTS = Path(__file__).parent / "results" / "data.json"
NOMINAL_RPM = np.array([1815.0, 1500.0, 450.0, 355.0])


def synthetic(rows: int, seed: int = 0) -> MeasurementSeries:
    """A 100 Hz recording with noise, 0.5 % missing samples and 0.1 % spikes (rpm)."""
    rng = np.random.default_rng(seed)
    rpm = NOMINAL_RPM * (1.0 + 0.002 * rng.standard_normal((rows, 4)))
    rpm[rng.random((rows, 4)) < 0.005] = np.nan
    spikes = rng.random((rows, 4)) < 0.001
    rpm[spikes] *= 1.5
    return MeasurementSeries(time_s=np.arange(rows) / 100.0, values=rpm)


def best_of(repeat: int, fn: Callable[[], Any]) -> tuple[float, Any]:
    """Smallest wall time (s) over ``repeat`` calls, and the last result."""
    times, result = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return min(times), result


def machine() -> dict[str, Any]:
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "python": platform.python_version(),
        "cpu_count": os.cpu_count(),
    }


def run(rows: int, repeat: int) -> list[tuple[str, float, str]]:
    """The measured figures as ``(figure, value, unit)``."""
    series = synthetic(rows)
    figures: list[tuple[str, float, str]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for suffix in (".csv", ".parquet"):
            path = Path(tmp) / f"bench{suffix}"
            t_write, _ = best_of(1, lambda p=path: write_measurements(series, p))
            t_read, loaded = best_of(repeat, lambda p=path: read_measurements(p))
            t_pre, _ = best_of(repeat, lambda s=loaded: preprocess(s))
            name = suffix[1:]
            figures += [
                (f"{name} file size", path.stat().st_size / 1e6, "MB"),
                (f"{name} write", t_write, "s"),
                (f"{name} load + validate", t_read, "s"),
                (f"{name} load + preprocess", t_read + t_pre, "s"),
                (f"{name} load rate", rows / t_read / 1e6, "Mrows/s"),
            ]
    t_pre, (_, report) = best_of(repeat, lambda: preprocess(series))
    figures.insert(0, ("preprocess (interpolate + smooth)", t_pre, "s"))
    figures.insert(0, ("rows x rollers", float(rows), "rows x 4"))
    figures.append(("samples filled", float(report.filled.sum()), "samples"))
    figures.append(("outliers replaced", float(report.outliers.sum()), "samples"))
    return figures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=1_000_000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()
    figures = run(args.rows, args.repeat)
    table = Table(title=f"drafttwin.data: {args.rows:,} rows x 4 rollers (best of {args.repeat})")
    for col in ("figure", "value", "unit"):
        table.add_column(col, justify="right" if col == "value" else "left")
    for name, value, unit in figures:
        table.add_row(name, f"{value:,.0f}" if value.is_integer() else f"{value:,.3f}", unit)
    Console().print(table)
    info, date = machine(), dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    records = [
        {"figure": n, "value": v, "unit": u, "machine": info, "date": date} for n, v, u in figures
    ]
    write_text_atomic(args.out, json.dumps(records, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
