"""Records: separate experiments kept apart inside one series.

A file is split into records where its integer ``record`` column changes; each record is put
on its own regular time grid (time may restart in every record). Several files are joined as
records of one series when they give the same channels, inputs, units and sample rate.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from drafttwin.data import validate as v
from drafttwin.data.columns import ColumnPlan
from drafttwin.data.series import MeasurementSeries
from drafttwin.data.units import normalise_unit
from drafttwin.errors import DataError

Bounds = list[tuple[int, int]]


def record_bounds(
    values: pd.Series, header: str, source: str | Path, row_label: v.RowLabel
) -> tuple[Bounds, np.ndarray]:
    """``[(start, stop), ...]`` rows of each record (a new record wherever the number changes)
    and the record number of each row; refuse empty, fractional or one-row records."""
    ids = v.numeric_column(values, header, source, row_label)
    bad = np.flatnonzero(~np.isfinite(ids) | (ids != np.round(ids)))
    if bad.shape[0]:
        i = int(bad[0])
        raise DataError(
            f"record number '{values.iloc[i]}' is not a whole number",
            source=source,
            where=f"{row_label(i)}, column '{header}'",
            fix="number the records 0, 1, 2, ... in every row of the 'record' column",
        )
    cuts = (np.flatnonzero(np.diff(ids) != 0) + 1).tolist()
    bounds = list(zip([0, *cuts], [*cuts, ids.shape[0]], strict=True))
    for a, b in bounds:
        if b - a < 2:
            raise DataError(
                f"record {ids[a]:g} has only one row; a sample rate needs at least two",
                source=source,
                where=f"{row_label(a)}, column '{header}'",
                fix="remove the row or give it the number of a neighbouring record",
            )
    return bounds, ids


def _offset_label(row_label: v.RowLabel, first: int) -> v.RowLabel:
    return row_label if first == 0 else (lambda i: row_label(i + first))


def record_on_grid(
    seconds: np.ndarray,
    data: dict[str, np.ndarray],
    plan: ColumnPlan,
    rows: tuple[int, int],
    source: str | Path,
    row_label: v.RowLabel,
    *,
    rate_tolerance: float,
    expected_rate_hz: float | None,
) -> tuple[MeasurementSeries, dict[str, Any]]:
    """File rows ``rows`` as one record on a regular grid (dropped rows become ``NaN`` rows),
    with the record's time offset, step, row count and inserted rows."""
    a, b = rows
    label = _offset_label(row_label, a)
    t = seconds[a:b]
    v.check_monotonic(t, source, label)
    positions, step = v.regular_grid(
        t, source, label, rate_tolerance=rate_tolerance, expected_rate_hz=expected_rate_hz
    )
    n_grid = int(positions[-1]) + 1

    def spread(x: np.ndarray) -> np.ndarray:
        x = x[a:b]
        if n_grid == x.shape[0]:
            return x
        out = np.full((n_grid, *x.shape[1:]), np.nan)
        out[positions] = x
        return out

    time_s = (
        t
        if n_grid == t.shape[0]
        else np.interp(np.arange(n_grid, dtype=np.float64), positions.astype(np.float64), t)
    )
    series = MeasurementSeries(
        time_s=time_s,
        values=np.column_stack([spread(data[c]) for c in plan.outputs])
        if plan.outputs
        else np.zeros((n_grid, 0)),
        channels=tuple(plan.outputs),
        units={k: u for k, u in plan.units.items() if k != "motor"},
        inputs={name: spread(data[name]) for name in plan.inputs},
        motor_rpm=spread(data["motor"]) if plan.motor else None,
    )
    meta = {
        "time_offset_s": float(t[0]),
        "sample_step_s": step,
        "rows_in_file": b - a,
        "inserted_rows": n_grid - (b - a),
    }
    return series, meta


def check_same_rate(
    steps: Sequence[float], names: Sequence[str], rate_tolerance: float, source: str | Path
) -> None:
    """Refuse records (or files) whose sample steps differ by more than ``rate_tolerance``."""
    for step, name in zip(steps[1:], names[1:], strict=True):
        if abs(step / steps[0] - 1.0) > rate_tolerance:
            raise DataError(
                f"sample rate {1 / step:.6g} Hz of {name} differs from {1 / steps[0]:.6g} Hz "
                f"of {names[0]} (more than {rate_tolerance:.2%})",
                source=source,
                where="time column",
                fix="resample the recordings to one rate, or read them separately",
            )


def join_records(
    parts: Sequence[MeasurementSeries], metas: Sequence[dict[str, Any]], top: dict[str, Any]
) -> MeasurementSeries:
    """Records side by side; ``metadata`` is ``top`` with ``records`` = ``metas``."""
    return replace(MeasurementSeries.concat(parts), metadata={**top, "records": list(metas)})


def _record_metas(part: MeasurementSeries) -> list[dict[str, Any]]:
    """One metadata dict per record of a file: the file's metadata with the record's own."""
    own = {k: val for k, val in part.metadata.items() if k != "records"}
    recs = part.metadata.get("records")
    if not isinstance(recs, list):
        return [own]
    return [{**own, **r} for r in recs]


def _refuse_mismatch(what: str, path: Path) -> None:
    raise DataError(
        what,
        source=path,
        where="columns",
        fix="give every file the same output and input columns in the same units, or read "
        "the files separately",
    )


def _check_compatible(
    part: MeasurementSeries, path: Path, first: MeasurementSeries, p0: Path
) -> None:
    if sorted(part.inputs) != sorted(first.inputs):
        got, want = sorted(part.inputs) or ["none"], sorted(first.inputs) or ["none"]
        _refuse_mismatch(f"inputs {', '.join(got)} here but {', '.join(want)} in {p0}", path)
    if (part.motor_rpm is None) != (first.motor_rpm is None):
        has, lacks = (path, p0) if part.motor_rpm is not None else (p0, path)
        _refuse_mismatch(f"a motor column in {has} but not in {lacks}", path)
    clash = _unit_clash(part, first)
    if clash is not None:
        name, here, there = clash
        _refuse_mismatch(f"'{name}' is in {here} here but in {there} in {p0}", path)


def _unit_clash(part: MeasurementSeries, first: MeasurementSeries) -> tuple[str, str, str] | None:
    """The first channel or input of ``first`` that ``part`` holds in another unit: its name
    and the two units (``no declared unit`` where none is), else ``None``."""
    for name in (*first.channels, *first.inputs):
        if name not in (*part.channels, *part.inputs):
            continue
        here, there = part.unit(name), first.unit(name)
        if normalise_unit(here) != normalise_unit(there):
            return name, here or "no declared unit", there or "no declared unit"
    return None


def join_files(
    parts: Sequence[MeasurementSeries], paths: Sequence[Path], rate_tolerance: float
) -> MeasurementSeries:
    """Several files as the records of one series (same channels, inputs, units and rate)."""
    first = parts[0]
    for part, path in zip(parts[1:], paths[1:], strict=True):
        _check_compatible(part, path, first, paths[0])
        check_same_rate(
            [first.metadata["sample_step_s"], part.metadata["sample_step_s"]],
            [str(paths[0]), str(path)],
            rate_tolerance,
            path,
        )
    metas = [m for part in parts for m in _record_metas(part)]
    columns: dict[str, str] = {}
    ignored: list[str] = []
    for part in parts:
        columns.update(part.metadata.get("columns", {}))
        ignored += [c for c in part.metadata.get("ignored_columns", []) if c not in ignored]
    top = {
        "source": ", ".join(str(p) for p in paths),
        "sources": [str(p) for p in paths],
        "columns": columns,
        "ignored_columns": ignored,
        "start_time": first.metadata.get("start_time"),
        "time_offset_s": first.metadata.get("time_offset_s"),
        "sample_step_s": first.metadata.get("sample_step_s"),
        "rows_in_file": sum(int(p.metadata.get("rows_in_file", len(p))) for p in parts),
        "inserted_rows": sum(int(p.metadata.get("inserted_rows", 0)) for p in parts),
    }
    return join_records(parts, metas, top)


def check_test_like_training(test: MeasurementSeries, train: MeasurementSeries) -> None:
    """Refuse separate test records that a model fitted on ``train`` would misread: another
    unit for one of its channels or inputs (a test record in mm scored against a model in m),
    or another sample rate (the windows would span another time). ``evaluate`` refuses the
    same against a model file; this is the same check at fit time."""
    clash = _unit_clash(test, train)
    if clash is not None:
        name, here, there = clash
        raise DataError(
            f"'{name}' is in {here} in the test records ({{test:name}}) but in {there} in the "
            "training records",
            param="test", terms={"test": None},
            fix="give both the same unit (convert the test records, or declare the units)",
        )  # fmt: skip
    if not np.isclose(test.sample_rate_hz, train.sample_rate_hz, rtol=0.01):
        raise DataError(
            f"the test records ({{test:name}}) are sampled at {test.sample_rate_hz:g} Hz but the "
            f"training records at "
            f"{train.sample_rate_hz:g} Hz",
            param="test", terms={"test": None},
            fix="resample the test records to the training rate (the model's windows span "
            "samples, not seconds)",
        )  # fmt: skip
