"""Checks on measurement files: every refusal is a :class:`~drafttwin.errors.DataError`.

Each check names the file, the place (row, line or column) and what to do. Rows are counted
as a spreadsheet user counts data rows: ``row 1`` is the first row below the header; for CSV
files the message adds the physical file line (the header is line 1).

Sampling policy (see ``docs/data.md``): samples must lie on a regular time grid. A time step
may deviate from the grid step by at most ``rate_tolerance`` (default 1 %) of the step. A step
that is a whole multiple ``k`` of the grid step (within the same tolerance) is a run of
``k - 1`` dropped rows: the reader re-inserts them as missing (``NaN``) samples. Any other step
is refused.
"""

from __future__ import annotations

import math
import re
import shlex
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from drafttwin.errors import DataError

RowLabel = Callable[[int], str]
"""Turns a 0-based data-row index into the place a user can find (``row 17 (line 18)``)."""

SUFFIXES: dict[str, str] = {".csv": "csv", ".parquet": "parquet", ".pq": "parquet"}
TIME_NAMES: tuple[str, ...] = (
    "time",
    "t",
    "time_s",
    "timestamp",
    "datetime",
    "date time",
    "date_time",
)
MOTOR_NAMES: tuple[str, ...] = ("motor", "motor_rpm")
IGNORE = "ignore"
TIME_UNITS: dict[str, float] = {
    "s": 1.0,
    "sec": 1.0,
    "ms": 1e-3,
    "msec": 1e-3,
    "us": 1e-6,
    "usec": 1e-6,
    "min": 60.0,
}
MAX_INSERTED_FACTOR = 10
"""Refuse a file whose dropped-row gaps would add more than this many times its row count."""


def default_row_label(i: int) -> str:
    """``row N`` with N the 1-based data row (the header is not counted)."""
    return f"row {i + 1}"


# --------------------------------------------------------------------------------- the file


def check_file(path: str | Path) -> str:
    """Return the format (``csv`` or ``parquet``) of an existing, non-empty file."""
    path = Path(path)
    if not path.exists():
        raise DataError(
            "file not found", source=path, fix="check the path (relative to the current folder)"
        )
    if not path.is_file():
        what = "a folder" if path.is_dir() else "a device or pipe, not a file"
        raise DataError(what, source=path, fix="give the path of a CSV or Parquet file")
    fmt = SUFFIXES.get(path.suffix.lower())
    if fmt is None:
        raise DataError(
            f"unsupported file type '{path.suffix or '(no suffix)'}'",
            source=path,
            fix="save the measurements as .csv or .parquet (.pq)",
        )
    if path.stat().st_size == 0:
        raise DataError("file is empty", source=path, fix="the file needs a header and data rows")
    return fmt


def check_has_rows(n_rows: int, source: str | Path) -> None:
    """Refuse a file with a header but no data rows."""
    if n_rows == 0:
        raise DataError(
            "no data rows (only a header)",
            source=source,
            fix="the file needs at least two rows of measurements below the header",
        )
    if n_rows < 2:
        raise DataError(
            "only one data row; a sample rate needs at least two",
            source=source,
            fix="export a longer recording",
        )


def sniff_separator(header_line: str) -> str:
    """The field separator of a CSV header line: ``,``, ``;`` or tab (comma by default)."""
    counts = {sep: header_line.count(sep) for sep in (",", ";", "\t")}
    best = max(counts, key=lambda s: counts[s])
    return best if counts[best] > 0 else ","


@dataclass(frozen=True)
class CsvLayout:
    """Where the data rows of a CSV file are: ``file_line[i]`` is the 1-based line of row i."""

    file_line: np.ndarray

    def label(self, i: int) -> str:
        if 0 <= i < self.file_line.shape[0]:
            return f"row {i + 1} (line {int(self.file_line[i])})"
        return default_row_label(i)


def check_field_counts(raw: bytes, sep: str, source: str | Path) -> CsvLayout:
    """Every non-blank line must have as many fields as the header (vectorised, no parsing).

    Lines with quoted fields cannot be counted this way; the check is then skipped (pandas
    still refuses rows with too many fields) and rows are assumed one per line.
    """
    if not raw[:4096].strip() and not raw.strip():
        raise DataError(
            "file has no header and no rows (only blank lines)",
            source=source,
            fix="the file needs a header and data rows",
        )
    buf = np.frombuffer(raw, dtype=np.uint8)
    newlines = np.flatnonzero(buf == 10)
    ends = newlines if raw.endswith(b"\n") else np.append(newlines, buf.shape[0])
    starts = np.concatenate(([0], newlines + 1))[: ends.shape[0]]
    lengths = ends - starts
    crlf = (lengths > 0) & (buf[np.maximum(ends - 1, 0)] == 13)
    nonblank = np.flatnonzero((lengths - crlf) > 0)
    header_line, data_lines = int(nonblank[0]), nonblank[1:]
    layout = CsvLayout(file_line=data_lines + 1)
    if raw.find(b'"', int(ends[header_line])) != -1:
        return layout
    seps = np.flatnonzero(buf == ord(sep))
    expected = int(np.count_nonzero(seps < ends[header_line]))
    if _each_line_has(seps, starts[nonblank], ends[nonblank], expected):
        return layout
    per_line = np.bincount(np.searchsorted(ends, seps), minlength=ends.shape[0])
    i = int(np.flatnonzero(per_line[data_lines] != expected)[0])
    raise DataError(
        f"{int(per_line[data_lines[i]]) + 1} fields but the header has {expected + 1}",
        source=source,
        where=layout.label(i),
        fix="every row needs one value per header column; leave a cell empty "
        f"(two '{sep}' in a row) for a missing sample, and remove trailing separators",
    )


def _each_line_has(seps: np.ndarray, starts: np.ndarray, ends: np.ndarray, k: int) -> bool:
    """Whether every line [start, end) holds exactly ``k`` of the sorted positions ``seps``.

    With ``k * lines`` positions in all, it suffices that group i's first position is not
    before line i's start and its last is before line i's end.
    """
    if seps.shape[0] != k * starts.shape[0] or (seps.shape[0] and seps[0] < starts[0]):
        return False
    if k == 0:
        return True
    groups = seps.reshape(-1, k)
    return bool((groups[:, 0] >= starts).all() and (groups[:, -1] < ends).all())


# ------------------------------------------------------------------------------ the columns


def time_scale(header: str, unit: str | None, source: str | Path) -> float:
    """Seconds per unit of a numeric time column whose header declares a unit."""
    if unit is None:
        return 1.0
    if unit in TIME_UNITS:
        return TIME_UNITS[unit]
    raise DataError(
        f"unknown time unit '{unit}'",
        source=source,
        where=f"column '{header}'",
        fix="give time in seconds (or ms, us, min in the header) or as ISO 8601 timestamps",
    )


def check_time_present(
    assigned: dict[str, str], headers: Sequence[str], source: str | Path
) -> None:
    """Refuse a file without a recognisable (or mapped) time column."""
    if "time" in assigned:
        return
    raise DataError(
        "no time column",
        source=source,
        where=f"columns: {', '.join(headers)}",
        fix=f"name the time column one of {', '.join(TIME_NAMES)} (seconds or ISO 8601 "
        "timestamps), or map it: --columns mytime=time",
    )


def check_channels_present(
    assigned: dict[str, str],
    headers: Sequence[str],
    names: Sequence[str],
    source: str | Path,
    kind: str = "roller",
) -> None:
    """Refuse a file lacking declared channel columns (``kind``: roller, output or input);
    the message lists the file's columns and suggests a ``--columns`` mapping from them."""
    missing = [r for r in names if r not in assigned]
    if not missing:
        return
    others = [h for h in headers if h not in assigned.values()]
    example = ",".join(f"{h}={r}" for h, r in zip(others, missing, strict=False)) or (
        ",".join(f"v{i + 1}={r}" for i, r in enumerate(missing))
    )
    what = ("the column " if len(names) == 1 else "the columns ") + ", ".join(names)
    what += " (speeds in rpm)" if kind == "roller" else ""
    raise DataError(
        f"missing {kind} column{'s' if len(missing) > 1 else ''}: {', '.join(missing)}",
        source=source,
        where=f"columns: {', '.join(headers)}",
        fix=f"name {what}, or map yours: --columns {shlex.quote(example)}",  # pasteable
    )


# ------------------------------------------------------------------------------- the values


def numeric_column(
    values: pd.Series, header: str, source: str | Path, row_label: RowLabel
) -> np.ndarray:
    """The column as float64 (``NaN`` = missing); refuse text or infinite cells."""
    if pd.api.types.is_bool_dtype(values.dtype) or not (
        pd.api.types.is_numeric_dtype(values.dtype)
    ):
        coerced = pd.to_numeric(values, errors="coerce")
        bad = np.flatnonzero(coerced.isna().to_numpy() & values.notna().to_numpy())
        if bad.shape[0] or pd.api.types.is_bool_dtype(values.dtype):
            i = int(bad[0]) if bad.shape[0] else 0
            _refuse_text(values.iloc[i], header, source, row_label(i))
        values = coerced
    out: np.ndarray = values.to_numpy(dtype=np.float64, na_value=np.nan)
    inf = np.flatnonzero(np.isinf(out))
    if inf.shape[0]:
        _refuse_text(values.iloc[int(inf[0])], header, source, row_label(int(inf[0])))
    return out


def _refuse_text(value: object, header: str, source: str | Path, where: str) -> None:
    text = str(value)
    fix = "replace it with a number, or leave the cell empty for a missing sample"
    if isinstance(value, float) and math.isinf(value):
        raise DataError(
            f"infinite value '{text}'", source=source, where=f"{where}, column '{header}'", fix=fix
        )
    if re.fullmatch(r"\s*-?\d+,\d+\s*", text):
        fix = "the file uses a decimal comma; export with a decimal point ('.')"
    raise DataError(
        f"non-numeric value '{text}'",
        source=source,
        where=f"{where}, column '{header}'",
        fix=fix,
    )


def refuse_unknown_text_columns(
    frame: pd.DataFrame, unknown: Sequence[str], source: str | Path
) -> list[str]:
    """Unknown numeric columns are ignored (returned); unknown text columns are refused."""
    ignored: list[str] = []
    for h in unknown:
        s = frame[h]
        if pd.api.types.is_numeric_dtype(s.dtype) or s.isna().all():
            ignored.append(h)
            continue
        raise DataError(
            f"unexpected non-numeric column '{h}'",
            source=source,
            where=f"column '{h}'",
            fix=f"delete the column, or drop it on reading with --columns '{h}'=ignore "
            "(a shifted or mis-separated file also shows up like this)",
        )
    return ignored


def check_not_all_missing(values: np.ndarray, header: str, source: str | Path) -> None:
    """Refuse a column without a single value."""
    if values.shape[0] and np.isnan(values).all():
        raise DataError(
            "no values (every cell is empty)",
            source=source,
            where=f"column '{header}'",
            fix="fill the column, or remove it (optional columns) / map another column to it",
        )


# --------------------------------------------------------------------------------- the time


def check_time_cells(
    bad: np.ndarray, values: pd.Series, header: str, source: str | Path, row_label: RowLabel
) -> None:
    """Refuse the first empty or unreadable time cell (``bad`` marks them)."""
    idx = np.flatnonzero(bad)
    if not idx.shape[0]:
        return
    i = int(idx[0])
    value = values.iloc[i]
    what = (
        "empty time cell"
        if pd.isna(value)
        else f"time value '{value}' is not a number of seconds nor an ISO 8601 timestamp"
    )
    fix = (
        "every row needs a time: seconds (0.01) or an ISO 8601 timestamp (2024-05-01T08:00:00.010)"
    )
    if re.fullmatch(r"\s*-?\d+,\d+\s*", str(value)):  # the first column a European export shows
        fix = "the file uses a decimal comma; export with a decimal point ('.')"
    unit = str(value).strip().strip("[]()").lower()
    if i == 0 and (unit in TIME_UNITS or unit in ("h", "hh:mm:ss", "sec.", "seconds")):
        what += ": a units row below the header?"
        fix = "delete that row (give units in the header instead: 'time [ms]', 'front [rpm]')"
    raise DataError(what, source=source, where=f"{row_label(i)}, column '{header}'", fix=fix)


def check_monotonic(t: np.ndarray, source: str | Path, row_label: RowLabel) -> None:
    """Time must strictly increase; name the first row that repeats or goes back."""
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if not bad.shape[0]:
        return
    i = int(bad[0]) + 1
    problem = (
        f"duplicate time stamp (same time as {row_label(i - 1)})"
        if dt[i - 1] == 0
        else f"time goes backwards by {-dt[i - 1]:.6g} s (from {row_label(i - 1)})"
    )
    raise DataError(
        problem,
        source=source,
        where=row_label(i),
        fix="sort the rows by time and remove duplicate rows; if the file joins several "
        "recordings, number them in an integer 'record' column or split it into one file per "
        "recording",
    )


def regular_grid(
    t: np.ndarray,
    source: str | Path,
    row_label: RowLabel,
    *,
    rate_tolerance: float = 0.01,
    expected_rate_hz: float | None = None,
) -> tuple[np.ndarray, float]:
    """Grid positions of the samples and the grid step (s); refuse irregular sampling.

    Returns ``positions`` (int64, ``positions[0] == 0``): sample i belongs at grid index
    ``positions[i]``; gaps between consecutive positions are dropped rows.
    """
    dt = np.diff(t)
    median = float(np.median(dt))
    step = median
    if expected_rate_hz is not None:
        step = 1.0 / float(expected_rate_hz)
        if abs(median / step - 1.0) > rate_tolerance:
            _refuse_rate(median, float(expected_rate_hz), source)
    ratio = dt / step
    k = np.rint(ratio)
    bad = np.flatnonzero((k < 1) | (np.abs(ratio - k) > rate_tolerance))
    if bad.shape[0]:
        i = int(bad[0]) + 1
        raise DataError(
            f"time step {dt[i - 1]:.6g} s is not a whole multiple of the sampling step "
            f"{step:.6g} s ({1 / step:.6g} Hz) within {rate_tolerance:.2%} of a step",
            source=source,
            where=row_label(i),
            fix="samples must lie on a regular time grid: resample the file onto one, or "
            "allow more jitter (rate_tolerance / --rate-tolerance). Dropped rows are fine: "
            "leave them out or as empty cells",
        )
    positions = np.concatenate(([0], np.cumsum(k.astype(np.int64))))
    _check_insertions(positions, k, step, source, row_label)
    return positions, step


def _refuse_rate(median: float, expected: float, source: str | Path) -> None:
    ratio = (1.0 / median) / expected
    hint = ""
    if abs(ratio * 1000 - 1) < 0.05:
        hint = "; the time column looks like milliseconds: name it 'time [ms]' or divide by 1000"
    raise DataError(
        f"sample rate is {1 / median:.6g} Hz (median step {median:.6g} s), expected {expected:.6g} Hz",
        source=source,
        where="time column",
        fix=f"check the file's sample rate and the expected rate{hint}",
    )


def _check_insertions(
    positions: np.ndarray, k: np.ndarray, step: float, source: str | Path, row_label: RowLabel
) -> None:
    n = positions.shape[0]
    inserted = int(positions[-1]) + 1 - n
    if inserted > MAX_INSERTED_FACTOR * n:
        i = int(np.argmax(k)) + 1
        raise DataError(
            f"time jumps by {k[i - 1] * step:.6g} s; filling the dropped rows would add "
            f"{inserted} empty rows to {n} measured ones",
            source=source,
            where=row_label(i),
            fix="this looks like several recordings joined together: split the file there, "
            "or number the recordings in an integer 'record' column",
        )


SUPPLY_HZ_MAX = 1000.0
"""The highest motor supply frequency a drive gives (VFD outputs stop at a few hundred Hz): one
sample of 4847 Hz (a lost decimal point) had moved a calibration's breakdown torque 2.80 ->
4.15 without a word."""


def check_supply_hz(values: np.ndarray, header: str, source: str | Path,
                    row_label: RowLabel) -> None:  # fmt: skip
    """Refuse a supply frequency above :data:`SUPPLY_HZ_MAX` (missing cells pass; a
    negative one is refused where a drive train follows it, with what a VFD's set-point is)."""
    bad = np.isfinite(values) & (values > SUPPLY_HZ_MAX)
    if not bad.any():
        return
    row = int(np.argmax(bad))
    raise DataError(
        f"supply frequency {values[row]:.6g} Hz is above the {SUPPLY_HZ_MAX:g} Hz a drive gives",
        source=source,
        where=f"{row_label(row)}, column '{header}'",
        fix="correct the cell (a lost decimal point?); the column is the motor's supply in Hz",
    )


def slow_clock_note(sample_rate_hz: float) -> str | None:
    """What to say of records that step by a whole number of seconds, 1 s or more: a time
    column in milliseconds read as seconds looks so (20 ms read as 20 s), and nothing else
    tells."""
    step = 1.0 / sample_rate_hz
    if step < 1.0 or abs(step - round(step)) > 1e-9:
        return None
    return (
        f"the records step by {step:g} s ({sample_rate_hz:.3g} Hz): if the time column "
        "counts milliseconds, name it 'time [ms]' (or divide it by 1000)"
    )
