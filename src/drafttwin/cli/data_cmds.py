"""``drafttwin inspect``: validate a measurement file and summarise it."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich import box
from rich.markup import escape
from rich.table import Table

from drafttwin.cli._data import ChannelOptions, pairs
from drafttwin.cli._groups import stops_cleanly, with_group
from drafttwin.cli._options import JsonOpt, number
from drafttwin.cli._oserrors import input_paths
from drafttwin.cli.typer_app import app, console, err_console, print_json
from drafttwin.data.extremes import describe
from drafttwin.data.io import read_measurements
from drafttwin.data.preprocessing import preprocess
from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import DataError


def parse_numbers(text: str | None, option: str) -> dict[str, float] | None:
    """``'front=1815,back=355'`` -> ``{'front': 1815.0, 'back': 355.0}``."""
    if not text:
        return None
    out: dict[str, float] = {}
    for key, value in pairs(text, option, "front=1815,back=355").items():
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
        return {"mean": None, "std": None, "min": None, "max": None}
    return {
        "mean": float(finite.mean()),
        "std": float(finite.std(ddof=1)) if finite.shape[0] > 1 else 0.0,
        "min": float(finite.min()),
        "max": float(finite.max()),
    }


def summarize(series: MeasurementSeries, *, outlier_threshold: float = 0.10) -> dict[str, Any]:
    """Rows, records, duration, rate, gaps, outliers (smoothing rule) and statistics per
    output channel and input, each in its unit."""
    _, report = preprocess(series, outlier_threshold=outlier_threshold)
    gaps = report.gaps()
    rules = report.rules
    channels = {
        c: {
            "unit": series.unit(c),
            **_stats(series.values[:, j]),
            "missing": report.n_missing[c],
            "gaps": gaps[c]["count"],
            "longest_gap": gaps[c]["longest"],
            "outliers": report.n_outliers[c],
            "outlier_rule": rules[c],
            "range_stretched": report.stretched.get(c),
        }
        for j, c in enumerate(series.channels)
    }
    inputs = {
        name: {"unit": series.unit(name), **_stats(v), "missing": int(np.isnan(v).sum())}
        for name, v in series.inputs.items()
    }
    meta = series.metadata
    return {
        "file": meta.get("source"),
        "rows": len(series),
        "records": series.n_records,
        "rows_in_file": meta.get("rows_in_file", len(series)),
        "inserted_rows": meta.get("inserted_rows", 0),
        "duration_s": series.duration_s,
        "sample_rate_hz": series.sample_rate_hz,
        "start_time": meta.get("start_time"),
        "columns": meta.get("columns", {}),
        "ignored_columns": meta.get("ignored_columns", []),
        "outlier_threshold": outlier_threshold,
        "channels": channels,
        "inputs": inputs,
        "motor": None if series.motor_rpm is None else _stats(series.motor_rpm),
    }


def _fmt(x: float | None, digits: int = 4) -> str:
    return "-" if x is None else f"{x:.{digits}g}"


def _print_summary(s: dict[str, Any]) -> None:
    head = Table.grid(padding=(0, 2))
    head.add_row("file", escape(str(s["file"])))
    rows = f"{s['rows']}"
    if s["inserted_rows"]:
        rows += f" ({s['rows_in_file']} in the file + {s['inserted_rows']} dropped rows as gaps)"
    if s["records"] > 1:
        rows += f" in {s['records']} records"
    head.add_row("rows", rows)
    head.add_row("duration", f"{s['duration_s']:.3f} s")
    head.add_row("sample rate", f"{s['sample_rate_hz']:.4g} Hz")
    if s["start_time"]:
        head.add_row("start", s["start_time"])
    head.add_row("columns", escape(", ".join(f"{k}->{v}" for k, v in s["columns"].items())))
    if s["ignored_columns"]:
        head.add_row("ignored", escape(", ".join(s["ignored_columns"])))
    if s["motor"]:
        head.add_row("motor", f"mean {_fmt(s['motor']['mean'])} rpm")
    for name, st in s["inputs"].items():
        unit = f" {st['unit']}" if st["unit"] else ""
        head.add_row(f"input {escape(name)}", f"{_fmt(st['min'])} to {_fmt(st['max'])}{unit}, "
                     f"{st['missing']} missing")  # fmt: skip
    console.print(head)
    table = Table(
        box=box.SIMPLE_HEAD,
        pad_edge=False,
        collapse_padding=True,
        title="output channels; missing and gaps in samples",
        caption=f"outliers: one-sample spikes > {s['outlier_threshold']:.0%} off both neighbours "
        "(of the value, or of the channel's spread for signals near or through zero)",
    )
    for col in ("channel", "unit", "mean", "std", "min", "max", "missing", "gaps", "longest",
                "outliers"):  # fmt: skip
        table.add_column(col, justify="left" if col in ("channel", "unit") else "right")
    for name, st in s["channels"].items():
        table.add_row(
            escape(name),
            escape(st["unit"] or "-"),
            _fmt(st["mean"]),
            _fmt(st["std"], 3),
            _fmt(st["min"]),
            _fmt(st["max"]),
            *(str(st[k]) for k in ("missing", "gaps", "longest_gap", "outliers")),
        )
    console.print(table)
    for name, st in s["channels"].items():
        if (found := st.get("range_stretched")) is not None:  # what the spike rule left
            console.print(f"[yellow]warning:[/] {escape(describe(name, found, st['unit']))}, a "
                          "glitch the one-sample spike rule leaves (a burst of wrong samples?); "
                          "a model scales the channel by that range",
                          highlight=False, soft_wrap=True)  # fmt: skip


FileArg = Annotated[str, typer.Argument(
    help="Measurement file(s) (.csv, .parquet), comma-separated for several experiments, or "
    "'default' (the embedded FA320A data).", callback=input_paths("FILE"))]  # fmt: skip
ExpectedRateOpt = Annotated[float | None, number("--rate", "Expected sample rate in Hz; refuse others.")]  # fmt: skip
NominalOpt = Annotated[str | None, typer.Option("--nominal", help="Nominal speeds in rpm "
                       "(front=1815,...) to detect unit mix-ups.")]  # fmt: skip
ThresholdOpt = Annotated[float, number("--threshold", "Outlier threshold (0.10 = 10 % of the "
                         "value, or of the channel's spread for signals near or through zero).")]  # fmt: skip


@app.command("inspect")
@stops_cleanly("nothing was written")
@with_group("channel_options", ChannelOptions)
def inspect_cmd(
    file: FileArg,
    channel_options: ChannelOptions,
    rate: ExpectedRateOpt = None,
    nominal: NominalOpt = None,
    threshold: ThresholdOpt = 0.10,
    as_json: JsonOpt = False,
) -> None:
    """Validate measurement files and summarise them.

    Prints rows, records, duration, sample rate, and per output channel (in its unit) mean,
    std, range, missing samples, gaps and outliers by the smoothing rule; inputs with their
    ranges. Without --outputs the FA320A rollers (rpm) are expected.

    A refused file exits with code 2 and a message naming the file, the row or column, and the fix.
    """
    if file == "default" and not Path(file).exists():
        from drafttwin.datasets import load_default

        series = load_default()
    else:
        channels = replace(channel_options.parse(), nominal_rpm=parse_numbers(nominal, "--nominal"))
        series = read_measurements([Path(p.strip()) for p in file.split(",") if p.strip()],
                                   expected_rate_hz=rate, **channels.reading())  # fmt: skip
    summary = summarize(series, outlier_threshold=threshold)
    from drafttwin.data.validate import slow_clock_note

    note = slow_clock_note(series.sample_rate_hz)  # as fit says it
    if note is not None:
        summary["notes"] = [note]
    if as_json:
        print_json(summary)
    else:
        _print_summary(summary)
        if note is not None:
            err_console.print(f"note: {escape(note)}", highlight=False, soft_wrap=True)
