"""``drafttwin inspect``: validate a measurement file and summarise it."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich import box
from rich.markup import escape
from rich.table import Table

from drafttwin.cli.app import app, console
from drafttwin.data.io import read_measurements
from drafttwin.data.preprocess import preprocess
from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import DataError


def parse_pairs(text: str | None, option: str) -> dict[str, str]:
    """``'v1=front,v2=second'`` -> ``{'v1': 'front', 'v2': 'second'}``."""
    if not text:
        return {}
    pairs: dict[str, str] = {}
    for item in text.split(","):
        key, sep, value = item.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise DataError(
                f"'{item}' is not NAME=VALUE",
                where=option,
                fix=f"write {option} v1=front,v2=second,v3=third,v4=back",
            )
        pairs[key.strip()] = value.strip()
    return pairs


def parse_numbers(text: str | None, option: str) -> dict[str, float] | None:
    """``'front=1815,back=355'`` -> ``{'front': 1815.0, 'back': 355.0}``."""
    if not text:
        return None
    out: dict[str, float] = {}
    for key, value in parse_pairs(text, option).items():
        try:
            out[key] = float(value)
        except ValueError:
            raise DataError(
                f"'{value}' is not a number", where=f"{option} {key}", fix="give numbers in rpm"
            ) from None
    return out


def _stats(x: np.ndarray) -> dict[str, float | None]:
    finite = x[np.isfinite(x)]
    if not finite.shape[0]:
        return {"mean_rpm": None, "std_rpm": None, "min_rpm": None, "max_rpm": None}
    return {
        "mean_rpm": float(finite.mean()),
        "std_rpm": float(finite.std(ddof=1)) if finite.shape[0] > 1 else 0.0,
        "min_rpm": float(finite.min()),
        "max_rpm": float(finite.max()),
    }


def summarize(series: MeasurementSeries, *, outlier_threshold: float = 0.10) -> dict[str, Any]:
    """Rows, duration, rate, gaps, outliers (smoothing rule) and per-roller statistics."""
    _, report = preprocess(series, outlier_threshold=outlier_threshold)
    gaps = report.gaps()
    rollers = {
        r: {
            **_stats(series.values[:, j]),
            "missing": report.n_missing[r],
            "gaps": gaps[r]["count"],
            "longest_gap": gaps[r]["longest"],
            "outliers": report.n_outliers[r],
        }
        for j, r in enumerate(series.channels)
    }
    meta = series.metadata
    return {
        "file": meta.get("source"),
        "rows": len(series),
        "rows_in_file": meta.get("rows_in_file", len(series)),
        "inserted_rows": meta.get("inserted_rows", 0),
        "duration_s": series.duration_s,
        "sample_rate_hz": series.sample_rate_hz,
        "start_time": meta.get("start_time"),
        "columns": meta.get("columns", {}),
        "ignored_columns": meta.get("ignored_columns", []),
        "outlier_threshold": outlier_threshold,
        "rollers": rollers,
        "motor": None if series.motor_rpm is None else _stats(series.motor_rpm),
        "setpoints": sorted(series.inputs),
    }


def _fmt(x: float | None, digits: int = 2) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def _print_summary(s: dict[str, Any]) -> None:
    head = Table.grid(padding=(0, 2))
    head.add_row("file", escape(str(s["file"])))
    rows = f"{s['rows']}"
    if s["inserted_rows"]:
        rows += f" ({s['rows_in_file']} in the file + {s['inserted_rows']} dropped rows as gaps)"
    head.add_row("rows", rows)
    head.add_row("duration", f"{s['duration_s']:.3f} s")
    head.add_row("sample rate", f"{s['sample_rate_hz']:.4g} Hz")
    if s["start_time"]:
        head.add_row("start", s["start_time"])
    head.add_row("columns", escape(", ".join(f"{k}->{v}" for k, v in s["columns"].items())))
    if s["ignored_columns"]:
        head.add_row("ignored", escape(", ".join(s["ignored_columns"])))
    if s["motor"]:
        head.add_row("motor", f"mean {_fmt(s['motor']['mean_rpm'])} rpm")
    if s["setpoints"]:
        head.add_row("set-points", escape(", ".join(s["setpoints"])))
    console.print(head)
    table = Table(
        box=box.SIMPLE_HEAD,
        pad_edge=False,
        collapse_padding=True,
        title="roller speeds (rpm); missing and gaps in samples",
        caption=f"outliers: one-sample spikes > {s['outlier_threshold']:.0%} off both neighbours",
    )
    for col in ("roller", "mean", "std", "min", "max", "missing", "gaps", "longest", "outliers"):
        table.add_column(col, justify="left" if col == "roller" else "right")
    for r, st in s["rollers"].items():
        table.add_row(
            escape(r),
            _fmt(st["mean_rpm"], 1),
            _fmt(st["std_rpm"], 3),
            _fmt(st["min_rpm"], 1),
            _fmt(st["max_rpm"], 1),
            *(str(st[k]) for k in ("missing", "gaps", "longest_gap", "outliers")),
        )
    console.print(table)


@app.command("inspect")
def inspect_cmd(
    file: Annotated[
        Path,
        typer.Argument(help="Measurement file (.csv, .parquet), or 'default' (embedded data)."),
    ],
    columns: Annotated[
        str | None,
        typer.Option(help="Map file columns to rollers / time / motor: v1=front,v2=second,..."),
    ] = None,
    time_column: Annotated[str | None, typer.Option(help="Name of the time column.")] = None,
    rate: Annotated[
        float | None,
        typer.Option(min=1e-9, help="Expected sample rate in Hz; refuse others."),
    ] = None,
    rate_tolerance: Annotated[
        float,
        typer.Option(min=0.0, max=0.49, help="Allowed time-step jitter, fraction of a step."),
    ] = 0.01,
    nominal: Annotated[
        str | None,
        typer.Option(help="Nominal roller speeds in rpm (front=1815,...) to detect unit mix-ups."),
    ] = None,
    unit_check: Annotated[
        bool, typer.Option("--unit-check/--no-unit-check", help="Run the unit heuristics.")
    ] = True,
    threshold: Annotated[
        float,
        typer.Option(min=0.0, help="Outlier threshold, relative to each neighbour (0.10 = 10 %)."),
    ] = 0.10,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")] = False,
) -> None:
    """Validate a measurement file and summarise it.

    Prints rows, duration, sample rate, missing samples and gaps, outliers (by the smoothing rule) and per-roller mean and std (rpm).

    A refused file exits with code 2 and a message naming the file, the row or column, and the fix.
    """
    if str(file) == "default" and not file.exists():
        from drafttwin.datasets import load_default

        series = load_default()
    else:
        series = read_measurements(
            file,
            columns=parse_pairs(columns, "--columns"),
            time_column=time_column,
            expected_rate_hz=rate,
            rate_tolerance=rate_tolerance,
            check_units=unit_check,
            nominal_rpm=parse_numbers(nominal, "--nominal"),
        )
    summary = summarize(series, outlier_threshold=threshold)
    if as_json:
        typer.echo(json.dumps(summary, indent=2))
    else:
        _print_summary(summary)
