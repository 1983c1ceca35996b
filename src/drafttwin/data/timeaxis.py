"""A measurement file's time column in seconds: numbers (in the unit its header gives), ISO
8601 timestamps, a European logger's day-first stamps, or Parquet durations."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from drafttwin.data import validate as v
from drafttwin.errors import DataError


@dataclass(frozen=True)
class TimeAxis:
    """Parsed time column in seconds (a numeric column as in the file, timestamps from the
    first one), plus the absolute start of timestamps."""

    seconds: np.ndarray
    start: str | None  # ISO 8601 timestamp of the first sample, when the file has timestamps
    offset_s: float  # the first value of a numeric time column (seconds), else 0


def parse_time(
    values: pd.Series, header: str, scale: float, source: str | Path, row_label: v.RowLabel
) -> TimeAxis:
    """Seconds for a numeric column (the file's own times, scaled by the header's unit) or an
    ISO 8601 timestamp column (seconds from the first timestamp).

    A text column whose cells are mostly numbers is read as seconds (so one bad cell is
    named, not the first good one); otherwise as timestamps.
    """
    if pd.api.types.is_datetime64_any_dtype(values.dtype):
        return _from_stamps(values, values, header, source, row_label)
    if pd.api.types.is_timedelta64_dtype(values.dtype):  # a duration: its own unit, not ns
        t = values.dt.total_seconds().to_numpy(dtype=np.float64, na_value=np.nan)
        v.check_time_cells(~np.isfinite(t), values, header, source, row_label)
        return TimeAxis(seconds=t, start=None, offset_s=float(t[0]))
    numbers = values
    if not pd.api.types.is_numeric_dtype(values.dtype) or pd.api.types.is_bool_dtype(values.dtype):
        head = values.dropna().iloc[:1000]  # decide on a sample: cheap for 1M timestamps
        if pd.to_numeric(head, errors="coerce").notna().sum() * 2 < head.shape[0]:
            stamps = _parse_timestamps(values, header, source)
            return _from_stamps(stamps, values, header, source, row_label)
        numbers = pd.to_numeric(values, errors="coerce")
    t = numbers.to_numpy(dtype=np.float64, na_value=np.nan) * scale
    v.check_time_cells(~np.isfinite(t), values, header, source, row_label)
    return TimeAxis(seconds=t, start=None, offset_s=float(t[0]))


def _from_stamps(
    stamps: pd.Series, values: pd.Series, header: str, source: str | Path, row_label: v.RowLabel
) -> TimeAxis:
    v.check_time_cells(stamps.isna().to_numpy(), values, header, source, row_label)
    delta = (stamps - stamps.iloc[0]).to_numpy().astype("timedelta64[ns]")
    seconds = delta.astype(np.int64).astype(np.float64) / 1e9
    return TimeAxis(seconds=seconds, start=pd.Timestamp(stamps.iloc[0]).isoformat(), offset_s=0.0)


DAY_FIRST = re.compile(r"\s*\d{1,2}\.\d{1,2}\.\d{4}[ T]\d{1,2}:\d{2}(:\d{2}(\.\d+)?)?\s*")
"""A European logger's stamp, day first (01.05.2024 08:00:00.010): never ambiguous, since
ISO 8601 separates the date with hyphens."""


def _parse_timestamps(values: pd.Series, header: str, source: str | Path) -> pd.Series:
    at = values.first_valid_index()
    first = "" if at is None else str(values.loc[at])
    m = DAY_FIRST.fullmatch(first)
    if m is not None:
        sep = "T" if "T" in first else " "
        clock = "%H:%M" + (":%S" if m.group(1) else "") + (".%f" if m.group(2) else "")
        return pd.to_datetime(values.astype(str).str.strip(), format=f"%d.%m.%Y{sep}{clock}",
                              errors="coerce")  # fmt: skip
    try:
        return pd.to_datetime(values, format="ISO8601", errors="coerce")
    except (ValueError, TypeError):  # e.g. mixed time-zone offsets
        try:
            return pd.to_datetime(values, format="ISO8601", errors="coerce", utc=True)
        except (ValueError, TypeError) as exc:
            raise DataError(
                f"time stamps cannot be read ({exc})",
                source=source,
                where=f"column '{header}'",
                fix="use ISO 8601 timestamps (2024-05-01T08:00:00.010) or seconds",
            ) from None
