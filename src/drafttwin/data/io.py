"""Reading and writing measurement files: CSV and Parquet.

File format (see ``docs/data.md``): one row per sample; a time column (seconds, or ISO 8601
timestamps converted to seconds from the first sample); one column per roller speed in rpm
(``front, second, third, back`` by default, other names mapped with ``columns``); optional
``motor`` (rpm) and set-point columns (``setpoint_*``, ``supply_hz``). Empty cells are missing
samples. Rows dropped from a regular time grid are re-inserted as missing samples.
"""

from __future__ import annotations

import io
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq

from drafttwin import ROLLERS
from drafttwin._io import atomic_path
from drafttwin.data import validate as v
from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import DataError

_META_KEY = b"drafttwin"


# ------------------------------------------------------------------------- column mapping


@dataclass
class ColumnPlan:
    """Which file column feeds which channel of a :class:`MeasurementSeries`."""

    time: str
    time_scale: float
    rollers: dict[str, str]  # roller -> file column
    motor: str | None = None
    setpoints: dict[str, str] = field(default_factory=dict)  # set-point name -> file column
    unknown: list[str] = field(default_factory=list)
    ignored: list[str] = field(default_factory=list)

    def used(self) -> dict[str, str]:
        """File column -> canonical name, for provenance."""
        out = {self.time: "time", **{c: r for r, c in self.rollers.items()}}
        if self.motor:
            out[self.motor] = "motor"
        out.update({c: s for s, c in self.setpoints.items()})
        return out


_UNIT_RE = re.compile(r"^(.*?)\s*[\[(]\s*([^\])]+?)\s*[\])]$")


def split_unit(name: str) -> tuple[str, str | None]:
    """``'front [rpm]'`` -> ``('front', 'rpm')``; ``'front_rpm'`` -> ``('front', 'rpm')``."""
    name = name.strip()
    m = _UNIT_RE.match(name)
    if m:
        return m.group(1).strip().lower(), m.group(2).replace(" ", "").lower()
    low = name.lower()
    if low.endswith("_rpm") and len(low) > 4:
        return low[:-4], "rpm"
    return low, None


def _is_setpoint(base: str) -> bool:
    return base.startswith("setpoint_") or base == "supply_hz"


def _mapping_targets(
    columns: dict[str, str], headers: Sequence[str], rollers: Sequence[str], source: str | Path
) -> dict[str, str]:
    """Resolve a user mapping {file column: target} against the headers (case-insensitive)."""
    by_lower = {h.strip().lower(): h for h in headers}
    allowed = (*rollers, "time", "motor", v.IGNORE)
    out: dict[str, str] = {}
    for key, target in columns.items():
        header = key if key in headers else by_lower.get(key.strip().lower())
        if header is None:
            raise DataError(
                f"mapped column '{key}' is not in the file",
                source=source,
                where="--columns",
                fix=f"the file's columns are: {', '.join(headers)}",
            )
        tgt = target.strip().lower()
        if tgt not in allowed and not _is_setpoint(tgt):
            raise DataError(
                f"unknown target '{target}' for column '{key}'",
                source=source,
                where="--columns",
                fix=f"map to one of {', '.join(allowed)}, or a name starting with 'setpoint_'",
            )
        out[header] = tgt
    return out


def plan_columns(
    headers: Sequence[str],
    source: str | Path,
    *,
    columns: dict[str, str] | None = None,
    time_column: str | None = None,
    rollers: Sequence[str] = ROLLERS,
) -> ColumnPlan:
    """Assign every file column to time, a roller, motor, a set-point, or ``unknown``."""
    headers = [str(h) for h in headers]
    mapping = _mapping_targets(columns or {}, headers, rollers, source)
    if time_column is not None:
        mapping.update(_mapping_targets({time_column: "time"}, headers, rollers, source))
    assigned: dict[str, str] = {}  # target -> header
    unknown: list[str] = []
    ignored = [h for h in headers if mapping.get(h) == v.IGNORE]
    explicit = [(h, t) for h, t in mapping.items() if t != v.IGNORE]
    defaults = [
        (h, _default_target(split_unit(h)[0], rollers)) for h in headers if h not in mapping
    ]
    for h, target in explicit + defaults:
        if target is None or (
            target in assigned and assigned[target] in mapping and h not in mapping
        ):
            unknown.append(h)  # unrecognised, or its default role is taken by a mapped column
        elif target in assigned:
            raise DataError(
                f"two columns give '{target}': '{assigned[target]}' and '{h}'",
                source=source,
                where=f"column '{h}'",
                fix=f"remove one, or drop it on reading with --columns '{h}'=ignore",
            )
        else:
            assigned[target] = h
    units = {t: split_unit(h)[1] for t, h in assigned.items()}
    v.check_time_present(assigned, headers, source)
    v.check_rollers_present(assigned, headers, rollers, source)
    for target, h in assigned.items():
        if (target in rollers or target == "motor") and units[target] is not None:
            v.refuse_unit(h, units[target], source)
    return ColumnPlan(
        time=assigned["time"],
        time_scale=v.time_scale(assigned["time"], units["time"], source),
        rollers={r: assigned[r] for r in rollers},
        motor=assigned.get("motor"),
        setpoints={t: h for t, h in assigned.items() if _is_setpoint(t)},
        unknown=[h for h in headers if h in unknown],
        ignored=ignored,
    )


def _default_target(base: str, rollers: Sequence[str]) -> str | None:
    if base in v.TIME_NAMES:
        return "time"
    if base in rollers:
        return base
    if base in v.MOTOR_NAMES:
        return "motor"
    if _is_setpoint(base):
        return base
    return None


# ----------------------------------------------------------------------------------- reading


@dataclass(frozen=True)
class TimeAxis:
    """Parsed time column: seconds from the first sample, plus its absolute start if known."""

    seconds: np.ndarray
    start: str | None  # ISO 8601 timestamp of the first sample, when the file has timestamps
    offset_s: float  # the first value of a numeric time column (seconds), else 0


def parse_time(
    values: pd.Series, header: str, scale: float, source: str | Path, row_label: v.RowLabel
) -> TimeAxis:
    """Seconds from start for a numeric (seconds) or ISO 8601 timestamp column.

    A text column whose cells are mostly numbers is read as seconds (so one bad cell is
    named, not the first good one); otherwise as timestamps.
    """
    if pd.api.types.is_datetime64_any_dtype(values.dtype):
        return _from_stamps(values, values, header, source, row_label)
    numbers = values
    if not pd.api.types.is_numeric_dtype(values.dtype) or pd.api.types.is_bool_dtype(values.dtype):
        head = values.dropna().iloc[:1000]  # decide on a sample: cheap for 1M timestamps
        if pd.to_numeric(head, errors="coerce").notna().sum() * 2 < head.shape[0]:
            stamps = _parse_timestamps(values, header, source)
            return _from_stamps(stamps, values, header, source, row_label)
        numbers = pd.to_numeric(values, errors="coerce")
    t = numbers.to_numpy(dtype=np.float64, na_value=np.nan) * scale
    v.check_time_cells(~np.isfinite(t), values, header, source, row_label)
    return TimeAxis(seconds=t - t[0], start=None, offset_s=float(t[0]))


def _from_stamps(
    stamps: pd.Series, values: pd.Series, header: str, source: str | Path, row_label: v.RowLabel
) -> TimeAxis:
    v.check_time_cells(stamps.isna().to_numpy(), values, header, source, row_label)
    delta = (stamps - stamps.iloc[0]).to_numpy().astype("timedelta64[ns]")
    seconds = delta.astype(np.int64).astype(np.float64) / 1e9
    return TimeAxis(seconds=seconds, start=pd.Timestamp(stamps.iloc[0]).isoformat(), offset_s=0.0)


def _parse_timestamps(values: pd.Series, header: str, source: str | Path) -> pd.Series:
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


def read_measurements(
    path: str | Path,
    *,
    columns: dict[str, str] | None = None,
    time_column: str | None = None,
    expected_rate_hz: float | None = None,
    rate_tolerance: float = 0.01,
    rollers: Sequence[str] = ROLLERS,
    check_units: bool = True,
    nominal_rpm: dict[str, float] | None = None,
    diameters_mm: dict[str, float] | None = None,
) -> MeasurementSeries:
    """Read and validate a CSV or Parquet measurement file.

    Args:
        path: ``.csv``, ``.parquet`` or ``.pq`` file.
        columns: file column -> role (a roller name, ``time``, ``motor``, ``setpoint_*``,
            ``supply_hz`` or ``ignore``), e.g. ``{"v1": "front"}``; names are case-insensitive.
        time_column: the time column's name when it is not one of ``time, t, time_s,
            timestamp, datetime``.
        expected_rate_hz: refuse the file unless its median sample rate matches (Hz).
        rate_tolerance: allowed deviation of a time step from the grid, as a fraction of a
            step (default 1 %).
        rollers: the roller columns required, in order.
        check_units: run the unit heuristics (plausible rpm range, front faster than back,
            ratio to ``nominal_rpm``).
        nominal_rpm: nominal speed per roller (rpm), to recognise rad/s, rev/s or m/min.
        diameters_mm: roller diameters (mm), to recognise surface speed in m/min.

    Returns:
        A :class:`MeasurementSeries` on a regular grid (time in s from the first sample, speeds
        in rpm, ``NaN`` = missing) with provenance in ``metadata``.

    Raises:
        DataError: for every problem with the file, naming file, row or column and the fix.
    """
    source = Path(path)
    fmt = v.check_file(source)
    raw = _read_csv(source) if fmt == "csv" else _read_parquet(source)
    frame, row_label = raw.frame, raw.row_label
    v.check_has_rows(len(frame), source)
    plan = plan_columns(
        list(frame.columns), source, columns=columns, time_column=time_column, rollers=rollers
    )
    ignored = plan.ignored + v.refuse_unknown_text_columns(frame, plan.unknown, source)
    axis = parse_time(frame[plan.time], plan.time, plan.time_scale, source, row_label)
    v.check_monotonic(axis.seconds, source, row_label)
    positions, step = v.regular_grid(
        axis.seconds,
        source,
        row_label,
        rate_tolerance=rate_tolerance,
        expected_rate_hz=expected_rate_hz,
    )
    channels = {
        role: _channel(frame, header, source, row_label) for role, header in _roles(plan).items()
    }
    rpm = np.column_stack([channels[r] for r in rollers])
    if check_units:
        v.check_units(rpm, rollers, source, nominal_rpm=nominal_rpm, diameters_mm=diameters_mm)
    metadata = {
        "source": str(source),
        "format": fmt,
        "columns": plan.used(),
        "ignored_columns": ignored,
        "start_time": axis.start,
        "time_offset_s": axis.offset_s,
        "sample_step_s": step,
        "rows_in_file": len(frame),
        "inserted_rows": int(positions[-1]) + 1 - len(frame),
        **raw.metadata,
    }
    return _on_grid(axis.seconds, positions, rpm, channels, plan, tuple(rollers), metadata)


@dataclass
class _Raw:
    frame: pd.DataFrame
    row_label: v.RowLabel
    metadata: dict[str, Any] = field(default_factory=dict)


def _read_csv(source: Path) -> _Raw:
    raw = source.read_bytes()
    if b"\x00" in raw[:4096]:
        raise DataError(
            "binary content, not CSV text",
            source=source,
            fix="export the measurements as CSV text, or give a Parquet file a .parquet suffix",
        )
    text_head = _decode(raw[:65536].split(b"\n", 1)[0], source)
    sep = v.sniff_separator(text_head)
    layout = v.check_field_counts(raw, sep, source)
    try:
        frame = pd.read_csv(
            io.BytesIO(raw),
            sep=sep,
            skipinitialspace=True,
            encoding=_encoding(raw),
            low_memory=False,
        )
    except (ValueError, UnicodeDecodeError, pd.errors.ParserError) as exc:
        raise DataError(
            f"cannot be read as CSV ({_first_line(exc)})",
            source=source,
            fix="save the file as comma-separated text with one header line",
        ) from None
    frame.columns = [str(c).strip() for c in frame.columns]
    _check_duplicate_headers(text_head, sep, source)
    return _Raw(frame=frame, row_label=layout.label, metadata={"separator": sep})


def _encoding(raw: bytes) -> str:
    try:
        raw.decode("utf-8")
    except UnicodeDecodeError:
        return "latin-1"
    return "utf-8-sig"


def _decode(line: bytes, source: Path) -> str:
    for enc in ("utf-8-sig", "latin-1"):
        try:
            return line.decode(enc)
        except UnicodeDecodeError:
            continue
    raise DataError("header line cannot be decoded", source=source, fix="save the file as UTF-8")


def _first_line(exc: BaseException) -> str:
    return str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__


def _check_duplicate_headers(header: str, sep: str, source: Path) -> None:
    if '"' in header:
        return
    names = [h.strip() for h in header.strip().split(sep)]
    seen: set[str] = set()
    for name in names:
        if name in seen:
            raise DataError(
                f"the header names column '{name}' twice",
                source=source,
                where="line 1 (header)",
                fix="give every column its own name",
            )
        seen.add(name)


def _read_parquet(source: Path) -> _Raw:
    try:
        table = pq.read_table(source)
    except (OSError, ValueError, pa.ArrowException) as exc:
        raise DataError(
            f"cannot be read as Parquet ({_first_line(exc)})",
            source=source,
            fix="check that the file is a complete Parquet file (or a CSV with a .csv suffix)",
        ) from None
    meta: dict[str, Any] = {}
    stored = (table.schema.metadata or {}).get(_META_KEY)
    if stored:
        meta["file_metadata"] = json.loads(stored)
    frame = table.to_pandas()
    frame = frame.reset_index(drop=True)
    frame.columns = [str(c).strip() for c in frame.columns]
    return _Raw(frame=frame, row_label=v.default_row_label, metadata=meta)


def _roles(plan: ColumnPlan) -> dict[str, str]:
    roles = dict(plan.rollers)
    if plan.motor:
        roles["motor"] = plan.motor
    roles.update(plan.setpoints)
    return roles


def _channel(frame: pd.DataFrame, header: str, source: Path, row_label: v.RowLabel) -> np.ndarray:
    values = v.numeric_column(frame[header], header, source, row_label)
    v.check_not_all_missing(values, header, source)
    return values


def _on_grid(
    seconds: np.ndarray,
    positions: np.ndarray,
    rpm: np.ndarray,
    channels: dict[str, np.ndarray],
    plan: ColumnPlan,
    rollers: tuple[str, ...],
    metadata: dict[str, Any],
) -> MeasurementSeries:
    """Place the samples on the regular grid; dropped rows become ``NaN`` rows."""
    n_grid = int(positions[-1]) + 1

    def spread(x: np.ndarray) -> np.ndarray:
        if n_grid == x.shape[0]:
            return x
        out = np.full((n_grid, *x.shape[1:]), np.nan)
        out[positions] = x
        return out

    time_s = (
        seconds
        if n_grid == seconds.shape[0]
        else np.interp(np.arange(n_grid, dtype=np.float64), positions.astype(np.float64), seconds)
    )
    return MeasurementSeries(
        time_s=time_s,
        values=spread(rpm),
        channels=rollers,
        motor_rpm=spread(channels["motor"]) if plan.motor else None,
        inputs={name: spread(channels[name]) for name in plan.setpoints},
        metadata=metadata,
    )


# ----------------------------------------------------------------------------------- writing


def write_measurements(series: MeasurementSeries, path: str | Path) -> Path:
    """Write a series as CSV or Parquet (by suffix), atomically; return the path.

    CSV: header ``time,front,second,third,back[,motor][,set-points]``, time in s, speeds in rpm,
    missing samples as empty cells, floats written so that they read back bit-identical.
    Parquet: the same columns; ``series.metadata`` is kept as JSON in the file's metadata.
    """
    target = Path(path)
    fmt = v.SUFFIXES.get(target.suffix.lower())
    if fmt is None:
        raise DataError(
            f"cannot write '{target.suffix or '(no suffix)'}' files",
            source=target,
            fix="use a .csv or .parquet file name",
        )
    frame = series.to_frame()
    table = pa.table({str(c): pa.array(frame[c].to_numpy(), from_pandas=True) for c in frame})
    with atomic_path(target) as tmp:
        if fmt == "csv":
            with open(tmp, "wb") as fh:
                fh.write((",".join(table.column_names) + "\n").encode("utf-8"))
                pa_csv.write_csv(table, fh, pa_csv.WriteOptions(include_header=False))
        else:
            meta = json.dumps(series.metadata, default=_jsonable).encode("utf-8")
            table = table.replace_schema_metadata(
                {**(table.schema.metadata or {}), _META_KEY: meta}
            )
            pq.write_table(table, tmp)
    return target


def _jsonable(obj: object) -> object:
    if isinstance(obj, np.ndarray | np.generic):
        return obj.tolist()
    return str(obj)
