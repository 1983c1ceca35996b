"""Simulator output files as a physics source: CSV/Parquet tables of a time column and one
column per channel (one table per record, or a ``record`` column), read, checked and
interpolated onto a record's time axis (:class:`~drafttwin.models.mechanistic.MechanisticModel`
given files)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pandas as pd

from drafttwin.data.series import MeasurementSeries
from drafttwin.data.timeaxis import parse_time
from drafttwin.data.validate import TIME_NAMES
from drafttwin.errors import DataError

TIME_COLUMNS = TIME_NAMES
"""Accepted names (case-insensitive) of the time column of a simulator output file, as of a
measurement file's: with a unit in brackets or as a suffix (``time [ms]``, ``time_ms``) or not
(seconds), or holding date stamps (``timestamp``: ISO 8601, day-first, a Parquet timestamp);
the record's own time column's name (``--time-column``) is accepted too."""


class Table(NamedTuple):
    """A simulator table: time (s) and columns by lower-cased name. A table stamped with
    dates (ISO 8601, a logger's day-first stamps, a Parquet timestamp) counts its seconds from
    its first stamp, ``start``; :meth:`in_frame_of` puts it on a record's own seconds."""

    time_s: np.ndarray
    columns: dict[str, np.ndarray]
    start: str | None = None

    def in_frame_of(self, record_start: str | None, table: str, record: str) -> Table:
        """The table on the time axis of a record whose seconds count from
        ``record_start`` (its file's first stamp; ``None``: a record timed in seconds).
        A table in seconds is taken as it is; a stamped one is moved by the stamps'
        difference, and refused for a record without stamps (its seconds have no date)."""
        if self.start is None:
            return self
        if record_start is None:
            raise _stamp_error(f"{table} is stamped with dates (from {self.start}) but its "
                               f"record {record} is timed in seconds, without a date",
                               "write the simulator's time in seconds on the record's own "
                               "axis, or give the record with its date stamps")  # fmt: skip
        try:
            shift = (pd.Timestamp(self.start) - pd.Timestamp(record_start)).total_seconds()
        except TypeError:  # one stamp has a time zone, the other none
            raise _stamp_error(f"{table} is stamped from {self.start} but its record {record} "
                               f"from {record_start}: one has a time zone, the other not",
                               "write both stamps with a time zone (2024-05-01T08:00:00+02:00) "
                               "or both without") from None  # fmt: skip
        return Table(self.time_s + shift, self.columns)


def _stamp_error(problem: str, fix: str) -> DataError:
    return DataError(f"{{mechanistic:name}} file {problem}", terms={"mechanistic": None},
                     param="mechanistic", fix=fix)  # fmt: skip


def read_table(path: Path) -> pd.DataFrame:
    """A simulator output file read through the checks every measurement file passes (a
    folder, an empty, binary or damaged file refused in one line naming it and
    ``--mechanistic``)."""
    from drafttwin.data.io import read_table as read_checked

    suffix = path.suffix.lower()
    if suffix == ".toml" and path.is_file():  # a drive-train file given as a simulator output
        raise DataError("a drive-train file, not a simulator output", source=path,
                        fix=f"to simulate it, give config:{path}")  # fmt: skip
    if suffix == ".txt":  # text tables are CSV, as before
        try:
            return pd.read_csv(path)
        except (ValueError, OSError) as exc:
            raise DataError(f"cannot read the file ({exc})", source=path,
                            fix="write the simulator output as .csv or .parquet") from exc  # fmt: skip
    return read_checked(path, option="--mechanistic")


def tables(frame: pd.DataFrame, source: str, time_column: str | None = None) -> list[Table]:
    """One table per record: a ``record`` column (as ``drafttwin predict`` writes for several
    records) splits the frame where it changes. ``time_column``: the record's time column's
    name, accepted as the table's time column too."""
    lower = {str(c).strip().lower(): c for c in frame.columns}
    if "record" not in lower:
        return [_table(frame, source, time_column)]
    ids = pd.to_numeric(frame[lower["record"]], errors="coerce").to_numpy(dtype=np.float64)
    _refuse_non_finite(ids, frame[lower["record"]], "record", source)
    cuts = np.flatnonzero(np.diff(ids) != 0) + 1
    parts = np.split(np.arange(len(frame)), cuts)
    return [_table(frame.iloc[rows].drop(columns=[lower["record"]]), f"{source} (record {k + 1})",
                   time_column) for k, rows in enumerate(parts)]  # fmt: skip


def _time_column(frame: pd.DataFrame, source: str, time_column: str | None) -> tuple[Any, float]:
    """The table's time column and its seconds per unit (``time [ms]``: 1e-3)."""
    from drafttwin.data.columns import time_header
    from drafttwin.data.validate import time_scale

    given = None if time_column is None else time_column.strip().lower()
    named = [c for c in frame.columns if str(c).strip().lower() == given]
    named += [c for c in frame.columns if time_header(str(c))[0] in TIME_COLUMNS]
    if not named:
        also = "" if given is None else ", or {time_column:value} as {time_column:name} names it"
        raise DataError(f"no time column (looked for {', '.join(TIME_COLUMNS)}{also})",
                        source=source, where=f"columns {list(map(str, frame.columns))}",
                        terms={"time_column": time_column},
                        fix="name the time column 'time' (seconds) or as the record's time "
                        "column")  # fmt: skip
    unit = time_header(str(named[0]))[1]
    return named[0], time_scale(str(named[0]), unit and unit.lower(), source)


def _table(frame: pd.DataFrame, source: str, time_column: str | None = None) -> Table:
    """Time (s) and numeric columns of a simulator table, checked."""
    if len(frame) < 2:
        raise DataError(f"{len(frame)} row(s); need at least 2", source=source)
    lower = {str(c).strip().lower(): c for c in frame.columns}
    time_col, seconds_per_unit = _time_column(frame, source, time_column)
    axis = parse_time(frame[time_col], str(time_col), seconds_per_unit, source,
                      lambda i: f"row {i + 1} (line {i + 2})")  # fmt: skip
    time_s = axis.seconds
    steps = np.diff(time_s)
    if (steps <= 0).any():
        row = int(np.argmax(steps <= 0)) + 1
        raise DataError("time is not strictly increasing", source=source,
                        where=f"data row {row}, column {time_col!r}",
                        fix="sort the simulator output by time and drop duplicate times")  # fmt: skip
    # other columns are checked when a channel uses them (the rest may be text or empty)
    cols = {name: frame[col] for name, col in lower.items() if col != time_col}
    values = {name: pd.to_numeric(col, errors="coerce").to_numpy(dtype=np.float64)
              for name, col in cols.items()}  # fmt: skip
    return Table(time_s, values, axis.start)


def _refuse_non_finite(values: np.ndarray, raw: pd.Series, column: str, source: str) -> None:
    bad = ~np.isfinite(values)
    if bad.any():
        row = int(np.argmax(bad))
        cell = raw.iloc[row]
        text = isinstance(cell, str) and cell.strip() != ""
        raise DataError(
            f"non-numeric value '{cell}'" if text else "a missing or non-numeric value",
            source=source,
            where=f"row {row + 1} (line {row + 2}), column {column!r}",
            fix="the simulator output must be complete numbers (time in seconds, values in "
            "the channels' units)",
        )


def interpolate(
    table: Table, time_s: np.ndarray, columns: list[str], names: tuple[str, ...], where: str
) -> np.ndarray:
    """The table's columns linearly interpolated onto ``time_s``.

    A simulator may stamp an interval's mean at its start or at its end, so the table may
    start or end up to one of its own steps inside the data's span: the edge value is held
    there. Anything further outside is refused.
    """
    table_t, table_cols = table.time_s, table.columns
    missing = [c for c in columns if c not in table_cols]
    if missing:
        raise DataError(
            f"no column(s) {missing} for the output channel(s) "
            f"{[n for n, c in zip(names, columns, strict=True) if c in missing]}",
            source=where,
            where=f"columns {sorted(table_cols)}",
            fix="write one column per output channel, named like the channel",
        )
    if time_s.size == 0:
        return np.zeros((0, len(columns)))
    step = float(np.median(np.diff(table_t)))
    tol = step * (1 + 1e-6)
    if time_s.min() < table_t[0] - tol or time_s.max() > table_t[-1] + tol:
        raise DataError(
            f"the simulator output covers {table_t[0]:g} s to {table_t[-1]:g} s but the data "
            f"span {time_s.min():g} s to {time_s.max():g} s{unit_hint(table_t, time_s)}",
            source=where,
            fix="simulate over the whole measurement span, on the same time axis (seconds, as "
            "in the data file's time column)",
        )
    out = []
    for column in columns:
        values = table_cols[column]
        _refuse_non_finite(values, pd.Series(values), column, where)
        out.append(np.interp(time_s, table_t, values))
    return np.column_stack(out)


def unit_hint(table_t: np.ndarray, time_s: np.ndarray) -> str:
    """ ", or ..." where the table's time runs a unit factor of the data's (a simulator's
    milliseconds in a column named ``time``), else ``""``."""
    table_span, data_span = float(np.ptp(table_t)), float(np.ptp(time_s))
    if not (table_span > 0 and data_span > 0):
        return ""
    ratio = table_span / data_span
    unit = next((u for u, f in (("ms", 1000.0), ("us", 1e6), ("min", 1 / 60))
                 if abs(ratio / f - 1) < 0.02), None)  # fmt: skip
    return "" if unit is None else (f", or its time column is in {unit} (its span is {ratio:.4g} "
                                    f"x the data's): name it 'time [{unit}]'")  # fmt: skip


def record_start(series: MeasurementSeries, k: int) -> str | None:
    """The first date stamp of record ``k``'s file (its seconds count from it), or ``None``
    for a record timed in seconds."""
    start = series.metadata.get("start_time")
    metas = series.metadata.get("records")
    if isinstance(metas, list) and len(metas) == series.n_records and isinstance(metas[k], dict):
        start = metas[k].get("start_time", start)
    return None if start is None else str(start)


def record_names(series: MeasurementSeries) -> list[str]:
    """Each record's file (``file (record k)`` for several records of one file) as the data
    were read, for messages."""
    metas = series.metadata.get("records")
    n = series.n_records
    if isinstance(metas, list) and len(metas) == n:
        files = [str(m.get("source", "")) if isinstance(m, dict) else "" for m in metas]
    else:
        files = [str(series.metadata.get("source", ""))] * n
    out = []
    for k, f in enumerate(files):
        label = f or "the data"
        out.append(label if files.count(f) == 1 else f"{label} (record {k + 1})")
    return out
