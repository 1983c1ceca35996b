"""Reading and writing measurement files: CSV and Parquet.

File format (see ``docs/data.md``): one row per sample; a time column (seconds, kept as in the
file, or ISO 8601 timestamps converted to seconds from the first sample); one column per
output channel (the four FA320A rollers in rpm by default, any names with ``outputs``), with
optional unit in the header (``y [m]``); optional ``motor`` (rpm), exogenous inputs (set-point
columns ``setpoint_*``, ``supply_hz`` by default, any names with ``inputs``) and an integer
``record`` column numbering separate experiments. Empty cells are missing samples. Rows
dropped from a record's regular time grid are re-inserted as missing samples.
"""

from __future__ import annotations

import io
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq

from drafttwin._io import atomic_path
from drafttwin.data import validate as v
from drafttwin.data.columns import RECORD, ChannelSpec, channel_spec, plan_columns
from drafttwin.data.records import (
    check_same_rate,
    join_files,
    join_records,
    record_bounds,
    record_on_grid,
)
from drafttwin.data.series import MeasurementSeries
from drafttwin.data.sniff import sniff
from drafttwin.data.timeaxis import parse_time
from drafttwin.data.units import check_units as check_rpm
from drafttwin.data.units import is_rpm
from drafttwin.errors import ConfigError, DataError

_META_KEY = b"drafttwin"
_UNITS_KEY = b"drafttwin.units"


# ----------------------------------------------------------------------------------- reading


def read_measurements(
    path: str | Path | Sequence[str | Path],
    *,
    outputs: Sequence[str] | None = None,
    inputs: Sequence[str] | None = None,
    units: Mapping[str, str] | None = None,
    time_column: str | None = None,
    columns: Mapping[str, str] | None = None,
    expected_rate_hz: float | None = None,
    rate_tolerance: float = 0.01,
    check_units: bool = True,
    nominal_rpm: dict[str, float] | None = None,
    diameters_mm: dict[str, float] | None = None,
    setpoints: bool = False,
) -> MeasurementSeries:
    """Read and validate CSV or Parquet measurement files.

    Args:
        path: a ``.csv``, ``.parquet`` or ``.pq`` file, or a sequence of them (separate
            experiments, joined as records; each file is validated on its own, and all must
            give the same outputs, inputs, units and sample rate).
        outputs: output channel names in order; ``None`` = the four FA320A rollers ``front,
            second, third, back`` in rpm. Headers match case-insensitively.
        inputs: exogenous input columns (each required); ``None`` = every set-point column
            (``setpoint_*``, ``supply_hz``) in the file; ``()`` = none.
        setpoints: with declared ``inputs``, also read the file's set-point columns (so a
            drive train's physics can follow the VFD set-point beside other inputs).
        units: unit per output or input (``{"y": "m", "u": "V"}``); it must agree with a
            unit in the header (``y [m]``). Default: rollers and motor rpm, ``supply_hz`` Hz,
            anything else undeclared (``""``).
        time_column: the time column's name when it is not one of ``time, t, time_s,
            timestamp, datetime``.
        columns: file column -> role (an output or input name, ``time``, ``motor``,
            ``record``, ``ignore``; with ``inputs=None`` also ``setpoint_*``, ``supply_hz``),
            e.g. ``{"v1": "front"}``; names are case-insensitive.
        expected_rate_hz: refuse a file unless its median sample rate matches (Hz).
        rate_tolerance: allowed deviation of a time step from the grid, and of one file's (or
            record's) rate from another's, as a fraction of a step (default 1 %).
        check_units: run the unit heuristics on the channels in rpm (plausible range, sign,
            front faster than back, ratio to ``nominal_rpm``).
        nominal_rpm: nominal speed per channel (rpm), to recognise rad/s, rev/s or m/min.
        diameters_mm: roller diameters (mm), to recognise surface speed in m/min.

    Returns:
        A :class:`MeasurementSeries` on a regular grid per record (time in s as in the file,
        or from the first timestamp; values in each channel's unit, ``NaN`` = missing),
        ``units`` per channel and input, and provenance in ``metadata``; for a record the
        plant wrote, the true values too (:func:`attach_truth`). A file with an
        integer ``record`` column, or several files, give several records.

    Raises:
        DataError: for every problem with a file, naming file, row or column and the fix.
        ConfigError: for contradictory or reserved ``outputs`` / ``inputs`` / ``units``.
    """
    spec = channel_spec(outputs, inputs, units, setpoints)
    paths = [Path(path)] if isinstance(path, str | Path) else [Path(p) for p in path]
    if not paths:
        raise ConfigError("no measurement file given", where="path", fix="name a file")
    opts = _Options(
        columns=dict(columns or {}),
        time_column=time_column,
        expected_rate_hz=expected_rate_hz,
        rate_tolerance=rate_tolerance,
        check_units=check_units,
        nominal_rpm=nominal_rpm,
        diameters_mm=diameters_mm,
    )
    parts = [attach_truth(_read_file(p, spec, opts), p) for p in paths]
    return parts[0] if len(parts) == 1 else join_files(parts, paths, rate_tolerance)


def attach_truth(series: MeasurementSeries, path: str | Path) -> MeasurementSeries:
    """If ``path`` was written by the plant (a ``<stem>.json`` sidecar naming a truth file sits
    beside it, holding every channel of ``series``), return the series with ``truth`` (the
    true values) and the defect masks in ``metadata``; else ``series`` unchanged.
    :func:`read_measurements` calls it on every file it reads."""
    path = Path(path)
    sidecar = path.with_suffix(".json")
    if not sidecar.is_file():
        return series
    try:
        truth_name = json.loads(sidecar.read_text(encoding="utf-8"))["files"]["truth"]
    except (ValueError, KeyError, TypeError, OSError):
        return series  # not a plant sidecar (a report, the user's own file)
    truth_path = path.with_name(str(truth_name))
    if not truth_path.is_file():
        return series
    frame = (
        pd.read_parquet(truth_path) if truth_path.suffix == ".parquet" else pd.read_csv(truth_path)
    )
    names = [f"{kind}_{r}" for kind in ("true", "missing", "outlier") for r in series.channels]
    if "time" not in frame or any(n not in frame for n in names):
        return series  # a truth file for other channels
    if len(frame) != len(series) or not np.allclose(frame["time"].to_numpy(), series.time_s):
        return series  # the measured file was edited: its truth no longer lines up
    meta = dict(series.metadata)
    truth = frame[[f"true_{r}" for r in series.channels]].to_numpy(np.float64)
    meta["missing_mask"] = frame[[f"missing_{r}" for r in series.channels]].to_numpy(bool)
    meta["outlier_mask"] = frame[[f"outlier_{r}" for r in series.channels]].to_numpy(bool)
    return replace(series, metadata=meta, truth=truth)


@dataclass(frozen=True)
class _Options:
    columns: dict[str, str]
    time_column: str | None
    expected_rate_hz: float | None
    rate_tolerance: float
    check_units: bool
    nominal_rpm: dict[str, float] | None
    diameters_mm: dict[str, float] | None


def _read_file(source: Path, spec: ChannelSpec, opts: _Options) -> MeasurementSeries:
    """One file: its columns, time, values and records, validated."""
    fmt = v.check_file(source)
    sniff(source, fmt)  # junk is refused from its first bytes, before it is read whole
    raw = _read_csv(source) if fmt == "csv" else _read_parquet(source)
    frame, row_label = raw.frame, raw.row_label
    v.check_has_rows(len(frame), source)
    plan = plan_columns(
        list(frame.columns),
        source,
        spec,
        columns=opts.columns,
        time_column=opts.time_column,
        stored_units=raw.units,
    )
    ignored = plan.ignored + v.refuse_unknown_text_columns(frame, plan.unknown, source)
    axis = parse_time(frame[plan.time], plan.time, plan.time_scale, source, row_label)
    data = {role: _channel(frame, col, source, row_label) for role, col in plan.roles().items()}
    if "supply_hz" in data:
        v.check_supply_hz(data["supply_hz"], plan.roles()["supply_hz"], source, row_label)
    if opts.check_units:
        rpm = [n for n in (*plan.outputs, *plan.inputs) if is_rpm(plan.units[n])]
        rpm += ["motor"] if plan.motor else []  # a motor column is in rpm (a sign, a unit)
        if rpm:
            check_rpm(np.column_stack([data[n] for n in rpm]), rpm, source,
                      nominal_rpm=opts.nominal_rpm, diameters_mm=opts.diameters_mm,
                      row_label=row_label)  # fmt: skip
    bounds, ids = [(0, len(frame))], None
    if plan.record:
        bounds, ids = record_bounds(frame[plan.record], plan.record, source, row_label)
    records = [
        record_on_grid(axis.seconds, data, plan, rows, source, row_label,
                       rate_tolerance=opts.rate_tolerance, expected_rate_hz=opts.expected_rate_hz)
        for rows in bounds
    ]  # fmt: skip
    metadata = {
        "source": str(source),
        "format": fmt,
        "columns": plan.used(),
        "ignored_columns": ignored,
        "start_time": axis.start,
        "time_offset_s": axis.offset_s,
        # predictions name their time column as the file did, where its values are the file's
        "time_column": plan.time if axis.start is None and plan.time_scale == 1 else "time",
        "sample_step_s": records[0][1]["sample_step_s"],
        "rows_in_file": len(frame),
        "inserted_rows": sum(meta["inserted_rows"] for _, meta in records),
        **raw.metadata,
    }
    if ids is None:
        return replace(records[0][0], metadata=metadata)
    names = [f"record {ids[a]:g} (from {row_label(a)})" for a, _ in bounds]
    check_same_rate([m["sample_step_s"] for _, m in records], names, opts.rate_tolerance, source)
    metas = [
        {**metadata, **meta, "record": int(ids[a]), "first_row": a + 1}
        for (a, _), (_, meta) in zip(bounds, records, strict=True)
    ]
    return join_records([s for s, _ in records], metas, metadata)


def read_table(path: str | Path, *, option: str | None = None) -> pd.DataFrame:
    """A CSV or Parquet table (any columns) read through the checks every measurement file
    passes: an existing, non-empty ``.csv`` / ``.parquet`` file, its first bytes sniffed
    (binary junk, a compressed or damaged file refused before it is read whole), the CSV's
    separator, encoding and field counts, at least one data row. Column names are stripped;
    values are as the file holds them (the caller checks its own columns and rows).

    Raises:
        DataError: naming the file and ``option`` (the CLI option it came from).
    """
    source = Path(path)
    try:
        fmt = v.check_file(source)
        sniff(source, fmt)
        raw = _read_csv(source) if fmt == "csv" else _read_parquet(source)
        if len(raw.frame) == 0:
            raise DataError("no data rows (only a header)", source=source,
                            fix="the file needs rows below the header")  # fmt: skip
    except DataError as exc:
        if option is None or exc.where is not None:
            raise
        raise DataError(exc.problem, source=exc.source, where=option, fix=exc.fix) from None
    return raw.frame


@dataclass
class _Raw:
    frame: pd.DataFrame
    row_label: v.RowLabel
    metadata: dict[str, Any] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)  # column -> unit kept in the file


def _read_csv(source: Path) -> _Raw:
    raw = source.read_bytes()
    if b"\x00" in raw[:4096]:
        raise DataError(
            "binary content, not CSV text",
            source=source,
            fix="export the measurements as CSV text, or give a Parquet file a .parquet suffix",
        )
    if b"\n" not in raw and b"\r" in raw:  # old-Mac line breaks (CR only): one line each
        raw = raw.replace(b"\r", b"\n")
    text_head = _decode(raw[:65536].split(b"\n", 1)[0], source)
    _refuse_preamble(text_head, source)
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


def _refuse_preamble(first: str, source: Path) -> None:
    """Refuse a first line that is no header, saying what it is (an Excel separator hint, a
    logger's comment lines above the header): they had read as "7 fields but the header has
    2" on the next line."""
    line = first.strip().lstrip("\ufeff")
    if line.lower().startswith("sep="):
        raise DataError(f"the first line '{line}' is Excel's separator hint, not a header",
                        source=source, where="line 1",
                        fix="delete that line (the separator is recognised by itself)")  # fmt: skip
    if line.startswith(("#", "//", ";")):
        raise DataError(f"the first line '{line[:40]}' is a comment, not a header",
                        source=source, where="line 1",
                        fix="delete the lines above the header (the column names)")  # fmt: skip


def _check_duplicate_headers(header: str, sep: str, source: Path) -> None:
    if '"' in header:
        return
    names = [h.strip() for h in header.strip().split(sep)]
    while names and not names[-1]:  # trailing separators: empty columns, dropped on reading
        names.pop()
    name = _named_twice(names)
    if name is not None:
        raise DataError(
            f"the header names column '{name}' twice",
            source=source,
            where="line 1 (header)",
            fix="give every column its own name",
        )


def _read_parquet(source: Path) -> _Raw:
    try:
        _refuse_repeated_names(pq.read_schema(source).names, source)
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
    units = json.loads((table.schema.metadata or {}).get(_UNITS_KEY) or b"{}")
    frame = table.to_pandas()
    # a named index (pandas' to_parquet of a frame indexed by its time) is a column of the file
    named = any(name is not None for name in frame.index.names)
    frame = frame.reset_index(drop=not named)
    frame.columns = [str(c).strip() for c in frame.columns]
    return _Raw(frame=frame, row_label=v.default_row_label, metadata=meta, units=units)


def _refuse_repeated_names(names: list[str], source: Path) -> None:
    """A Parquet schema naming a column twice (Arrow's "Multiple matches for FieldRef")."""
    name = _named_twice(names)
    if name is not None:
        raise DataError(f"the file names column '{name}' twice", source=source,
                        fix="write the file with each column once")  # fmt: skip


def _named_twice(names: list[str]) -> str | None:
    """The first name that comes a second time, else ``None``."""
    seen: set[str] = set()
    for name in names:
        if name in seen:
            return name
        seen.add(name)
    return None


def _channel(frame: pd.DataFrame, header: str, source: Path, row_label: v.RowLabel) -> np.ndarray:
    values = v.numeric_column(frame[header], header, source, row_label)
    v.check_not_all_missing(values, header, source)
    return values


# ----------------------------------------------------------------------------------- writing


def write_measurements(series: MeasurementSeries, path: str | Path) -> Path:
    """Write a series as CSV or Parquet (by suffix), atomically; return the path.

    Columns: ``time`` (s), the output channels, ``motor`` (if any), the inputs, and ``record``
    (the record number of each row) when the series has several records. Missing samples are
    empty cells (CSV) or nulls; floats are written so that they read back bit-identical. CSV
    headers are the plain names (give units with ``units=`` when reading). Parquet also keeps
    ``series.metadata`` and the unit of every channel and input, read back into ``units``.
    """
    target = Path(path)
    fmt = v.SUFFIXES.get(target.suffix.lower())
    if fmt is None:
        raise DataError(
            f"cannot write '{target.suffix or '(no suffix)'}' files",
            source=target,
            fix="use a .csv or .parquet file name",
        )
    _check_column_names(series, target)
    frame = series.to_frame()
    table = pa.table({str(c): pa.array(frame[c].to_numpy(), from_pandas=True) for c in frame})
    with atomic_path(target) as tmp:
        if fmt == "csv":
            with open(tmp, "wb") as fh:
                fh.write((",".join(table.column_names) + "\n").encode("utf-8"))
                pa_csv.write_csv(table, fh, pa_csv.WriteOptions(include_header=False))
        else:
            meta = json.dumps(series.metadata, default=_jsonable).encode("utf-8")
            units = {n: series.unit(n) for n in (*series.channels, *series.inputs)}
            if series.motor_rpm is not None:
                units["motor"] = "rpm"
            stored = json.dumps({n: u for n, u in units.items() if u}).encode("utf-8")
            table = table.replace_schema_metadata(
                {**(table.schema.metadata or {}), _META_KEY: meta, _UNITS_KEY: stored}
            )
            pq.write_table(table, tmp)
    return target


def _check_column_names(series: MeasurementSeries, target: Path) -> None:
    """Every written column needs its own name, distinct from time, motor and record."""
    names = ["time", *series.channels, *(["motor"] if series.motor_rpm is not None else [])]
    names += [*series.inputs, *([RECORD] if series.n_records > 1 else [])]
    seen: set[str] = set()
    for name in names:
        if name.lower() in seen:
            raise DataError(
                f"two columns would be named '{name}'",
                source=target,
                where="channels and inputs",
                fix="rename the channel or input (time, motor and record are taken)",
            )
        seen.add(name.lower())


def _jsonable(obj: object) -> object:
    if isinstance(obj, np.ndarray | np.generic):
        return obj.tolist()
    return str(obj)
