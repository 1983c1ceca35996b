"""The mechanistic prediction as a pluggable source.

A mechanistic model depends only on the machine and its settings (set-points, exogenous
inputs), so its prediction for any sample is known in advance and may be used up to and
including the target time. Sources:

* a drive train (:meth:`MechanisticModel.from_train`, :meth:`~MechanisticModel.from_preset`,
  :meth:`~MechanisticModel.from_config`): simulated on each record's time grid, following the
  record's input channels (the VFD supply frequency ``supply_hz``, or what the train's
  ``[[input]]`` tables map), giving the output channels its ``[[output]]`` tables (or node and
  roller names) name;
* a simulator's output file (CSV/Parquet: a time column in seconds and one column per output
  channel), or several, one per record: aligned on the data's own time axis and linearly
  interpolated onto it; any start time, refused only where it does not cover the data;
* a ``pandas.DataFrame`` with the same columns;
* a Python callable ``f(time_s)`` or ``f(time_s, inputs)`` (``inputs``: dict of the record's
  input channels) returning ``(n, channels)`` values, or a DataFrame / dict by channel name;
* a function of the whole record (:meth:`MechanisticModel.from_series_function`);
* a precomputed ``(n, channels)`` array aligned row by row with the series.

:meth:`MechanisticModel.predict` returns the requested channels (by default the series'),
computed record by record, as a labelled frame like every model's; :meth:`~MechanisticModel.predict_values`
returns them as an array (what the estimators and hybrids combine with).
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import DataError
from drafttwin.models.mechanistic.simfiles import (
    Table,
    interpolate,
    read_table,
    record_names,
    record_start,
    tables,
    unit_hint,
)
from drafttwin.models.mechanistic.source import parse_source
from drafttwin.models.mechanistic.values import (
    RecordFunction,
    adapt_callable,
    check_values,
    is_path_list,
)

if TYPE_CHECKING:
    from drafttwin.mechanics import DriveTrain


class MechanisticModel:
    """A mechanistic source: the physics' prediction of the output channels.

    Args:
        source: a callable, a simulator output file path (or a list of paths, one per record),
            a DataFrame or an aligned array; see the module docstring. Drive trains: use
            :meth:`from_train`, :meth:`from_preset` or :meth:`from_config`.
        columns: optional mapping ``channel -> column name`` for files and tables whose
            columns are named otherwise.
        name: a label for reports (defaults to a description of the source).
        channels: the channels an array or a callable returns, in column order (default: the
            channels asked for at prediction time).
        time_column: the records' time column's name, accepted as a file's or table's time
            column besides ``time``, ``time_s`` and ``t``.
    """

    def __init__(
        self,
        source: Any,
        *,
        columns: Mapping[str, str] | None = None,
        name: str | None = None,
        channels: Sequence[str] | None = None,
        time_column: str | None = None,
    ) -> None:
        self.channels: tuple[str, ...] | None = None if channels is None else tuple(channels)
        self._columns = {k: str(v).lower() for k, v in (columns or {}).items()}
        self._array: np.ndarray | None = None
        self._tables: list[Table] = []
        self._table_names: list[str] = []
        self._record_fn: RecordFunction | None = None
        self._series_fn: Callable[[MeasurementSeries], np.ndarray] | None = None
        self._inputs: tuple[str, ...] = ()
        self.train: DriveTrain | None = None
        """The drive train simulated (:meth:`from_train` and the sources built on it)."""
        self._spec: dict[str, Any]
        if isinstance(source, str | Path) or is_path_list(source):
            paths = [Path(p) for p in ([source] if isinstance(source, str | Path) else source)]
            per_file = [tables(read_table(p), str(p), time_column) for p in paths]
            self._tables = [t for ts in per_file for t in ts]
            self._table_names = [
                str(p) if len(ts) == 1 else f"{p} (record {k + 1})"
                for p, ts in zip(paths, per_file, strict=True)
                for k in range(len(ts))
            ]
            self._spec = {"kind": "file", "paths": [str(p) for p in paths]}
            label = ", ".join(str(p) for p in paths)
        elif isinstance(source, pd.DataFrame):
            self._tables = tables(source, "mechanistic table", time_column)
            self._table_names = [f"mechanistic table (record {k + 1})" if len(self._tables) > 1
                                 else "mechanistic table" for k in range(len(self._tables))]  # fmt: skip
            self._spec, label = {"kind": "table"}, "table"
        elif isinstance(source, np.ndarray):
            self._array = np.asarray(source, dtype=np.float64)
            if self._array.ndim == 1:
                self._array = self._array[:, None]
            self._spec, label = {"kind": "array"}, "array"
        elif callable(source):
            self._record_fn = adapt_callable(source)
            self._spec, label = {"kind": "callable"}, getattr(source, "__name__", "callable")
        else:
            raise DataError(
                f"cannot use a {type(source).__name__} as a mechanistic source",
                fix="pass a drive train (MechanisticModel.from_train), a simulator output file, "
                "a DataFrame, a callable f(time_s[, inputs]) or an (n, channels) array",
            )
        self.name = name or label

    # ----- constructors -------------------------------------------------------------------
    @classmethod
    def _from_function(
        cls, fn: RecordFunction, spec: dict[str, Any], name: str
    ) -> MechanisticModel:
        model = cls(fn, name=name)  # a callable source, then its real calling convention
        model._record_fn, model._spec = fn, spec
        return model

    @classmethod
    def from_train(cls, train: DriveTrain, *, name: str | None = None) -> MechanisticModel:
        """A drive train simulated on each record's grid, following its input channels."""
        from drafttwin.mechanics import simulate
        from drafttwin.mechanics.components import OUTPUT_UNITS
        from drafttwin.mechanics.inputs import select_outputs

        cache: dict[bytes, np.ndarray] = {}

        def run(time_s: np.ndarray, inputs: dict[str, np.ndarray], channels: tuple[str, ...],
                units: dict[str, str]) -> np.ndarray:  # fmt: skip
            speed = {c: u for c, u in units.items() if u in OUTPUT_UNITS}  # else the train's
            key = b"|".join([np.ascontiguousarray(time_s).tobytes(), repr((channels, speed)).encode(),
                             *(np.ascontiguousarray(v).tobytes() for _, v in sorted(inputs.items()))])  # fmt: skip
            if key not in cache:
                cache.clear()  # one record at a time is what fit/predict re-use
                select_outputs(train, channels, speed)  # refused before the simulation runs
                res = simulate(train, time_s=time_s, inputs=inputs)
                cache[key] = res.channels(channels, speed)
            return cache[key]

        spec = {"kind": "train", "name": train.spec.train.name, "source": str(train.source),
                "spec": train.spec.model_dump(mode="json", exclude_defaults=True),
                **_reduction_spec(train)}  # fmt: skip
        label = name or f"drive train {train.spec.train.name}"
        model = cls._from_function(run, spec, label + _reduction_label(train))
        model._inputs = tuple(c.channel for c in train.spec.input)  # declared: required
        model.train = train
        return model

    @classmethod
    def from_preset(
        cls, preset: str = "fa320a", *, cutoff_hz: float | None = None
    ) -> MechanisticModel:
        """The built-in drive train ``preset`` (see :func:`from_train`), reduced
        (:func:`drafttwin.mechanics.reduce`) at ``cutoff_hz`` when given."""
        from drafttwin.mechanics import DriveTrain

        train = _reduced(DriveTrain.preset(preset), cutoff_hz)
        model = cls.from_train(train, name=f"preset {preset}")
        model._spec = {"kind": "preset", "name": preset, **_reduction_spec(train)}
        return model

    @classmethod
    def from_config(cls, path: str | Path, *, cutoff_hz: float | None = None) -> MechanisticModel:
        """A drive train declared in a TOML file (see :func:`from_train`), reduced at
        ``cutoff_hz`` when given."""
        from drafttwin.mechanics import DriveTrain

        train = _reduced(DriveTrain.from_toml(Path(path)), cutoff_hz)
        return cls.from_train(train, name=f"config {path}")

    @classmethod
    def from_series_function(
        cls,
        func: Callable[[MeasurementSeries], np.ndarray],
        *,
        channels: Sequence[str] | None = None,
        name: str | None = None,
    ) -> MechanisticModel:
        """A source computed from each whole record, ``func(record) -> (n, channels)``.

        For a simulation driven by the record's inputs and its initial measured state (in a
        simulation the outputs after the initialisation window are NaN). Not stored in model
        files (pass it again to ``predict``).
        """
        model = cls(func, channels=channels, name=name or "series function")
        model._record_fn, model._series_fn = None, func
        model._spec = {"kind": "series-callable"}
        return model

    @classmethod
    def from_option(
        cls, text: str, *, cutoff_hz: float | None = None, time_column: str | None = None
    ) -> MechanisticModel:
        """The source named by a command-line value: ``preset``, ``preset:NAME``,
        ``config:FILE.toml`` or a simulator output file (``FILE[,FILE...]``, one per record).
        ``cutoff_hz`` reduces a drive train (files are taken as they are); ``time_column``:
        the records' time column's name, accepted in the files too."""
        source = parse_source(text, "--mechanistic")
        if source.kind == "preset":
            return cls.from_preset(source.preset, cutoff_hz=cutoff_hz)
        if source.kind == "config":
            return cls.from_config(source.paths[0], cutoff_hz=cutoff_hz)
        return cls([str(p) for p in source.paths], time_column=time_column)

    @classmethod
    def from_spec(cls, spec: Mapping[str, Any] | None) -> MechanisticModel | None:
        """Rebuild a source recorded by :meth:`spec` when it is self-contained (a preset, a
        drive train), else ``None`` (files, callables, tables and arrays are passed again)."""
        if not spec:
            return None
        cutoff_hz = spec_cutoff_hz(spec)
        if spec.get("kind") == "preset":
            return cls.from_preset(str(spec["name"]), cutoff_hz=cutoff_hz)
        if spec.get("kind") == "train":
            from drafttwin.mechanics import DriveTrain

            train = DriveTrain.from_dict(dict(spec["spec"]), source=f"model file ({spec['name']})")
            return cls.from_train(_reduced(train, cutoff_hz), name=f"drive train {spec['name']}")
        return None

    def split_records(
        self, first: int, second: int, records: Sequence[str] | None = None
    ) -> tuple[MechanisticModel, MechanisticModel]:
        """Sources for two series of ``first`` and ``second`` records: simulator tables, one
        per record (training records, then test records), are cut in two; any other source
        serves both. Tables in another number are refused (:meth:`match_records`): the
        training records' simulator output is never reused for a test record (``records``:
        the records' names for the message)."""
        if not self._tables:
            return self, self
        if len(self._tables) != first + second:
            raise self._count_error(first + second, "the training and test records", records)
        a, b = copy.copy(self), copy.copy(self)
        a._tables, b._tables = self._tables[:first], self._tables[first:]
        a._table_names, b._table_names = self._table_names[:first], self._table_names[first:]
        if "paths" in self._spec:
            files = list(dict.fromkeys(n.split(" (record ")[0] for n in a._table_names))
            a._spec = {**self._spec, "paths": files}
            b._spec = {**self._spec, "paths": list(dict.fromkeys(
                n.split(" (record ")[0] for n in b._table_names))}  # fmt: skip
        return a, b

    def match_records(self, series: MeasurementSeries) -> None:
        """Refuse simulator tables that do not match the records of ``series`` (whole
        records, as read): one table per record, in order, each spanning its own record's
        time grid (start and end within one sample step, the coarser of the two grids). A
        table for another record (another span or length) is refused naming both files;
        other sources are not checked."""
        if not self._tables:
            return
        bounds = series.record_bounds()
        if len(self._tables) != len(bounds):
            raise self._count_error(len(bounds), "the records", record_names(series))
        names = record_names(series)
        for k, (a, b) in enumerate(bounds):
            table_t, time_s = self._aligned(series, k).time_s, series.time_s[a:b]
            if len(time_s) < 2:
                continue
            step = max(float(np.median(np.diff(table_t))), float(np.median(np.diff(time_s))))
            tol = step * (1 + 1e-6)
            if abs(table_t[0] - time_s[0]) <= tol and abs(table_t[-1] - time_s[-1]) <= tol:
                continue
            raise DataError(
                f"{{mechanistic:name}} file {self._table_names[k]} covers {table_t[0]:g} s to "
                f"{table_t[-1]:g} s ({len(table_t)} rows) but its record {names[k]} spans "
                f"{time_s[0]:g} s to {time_s[-1]:g} s ({len(time_s)} rows)"
                f"{self._stamps_note(series, k)}: it is the simulator output of another "
                f"record{unit_hint(table_t, time_s)}",
                terms={"mechanistic": self.name},
                param="mechanistic",
                fix="give the simulator output of each record, simulated over that record's "
                "own time axis, one file per record in the order of the records",
            )

    def grid_shifts(self, series: MeasurementSeries) -> list[tuple[str, str, float]]:
        """Tables whose grid is their record's shifted by a whole step (the table's first
        time one step before or after the record's, both on one step): ``(table, record,
        shift_s)``. Accepted (a simulator may stamp a step at its start or its end), but a
        wrong convention moves the physics by a step (31 % of a speed change's RMSE)."""
        if not self._tables or len(self._tables) != series.n_records:
            return []
        names, out = record_names(series), []
        for k, (a, b) in enumerate(series.record_bounds()):
            table_t, time_s = self._aligned(series, k).time_s, series.time_s[a:b]
            if len(time_s) < 2 or len(table_t) < 2:
                continue
            step, own = float(np.median(np.diff(time_s))), float(np.median(np.diff(table_t)))
            shift = float(table_t[0] - time_s[0])
            if abs(own / step - 1) < 1e-3 and abs(abs(shift) / step - 1) < 0.01:
                out.append((self._table_names[k], names[k], shift))
        return out

    def _count_error(
        self, n_records: int, what: str, records: Sequence[str] | None = None
    ) -> DataError:
        files = ", ".join(self._table_names)
        named = "" if not records else f" ({', '.join(records)})"
        return DataError(
            f"{{mechanistic:name}} gives {len(self._tables)} simulator output table(s) "
            f"({files}) for {n_records} records{named}: a record's simulator output is never "
            "reused for another record",
            terms={"mechanistic": self.name},
            param="mechanistic",
            fix=f"give one simulator file per record for {what}, in their order (training "
            "records first), or one file with a record column",
        )

    @property
    def n_tables(self) -> int:
        """Simulator tables (one per record) of a file or table source; 0 for others."""
        return len(self._tables)

    def required_inputs(self) -> tuple[str, ...]:
        """Input channels the source needs in the data (a drive train's ``[[input]]``s)."""
        return self._inputs

    def spec(self) -> dict[str, Any]:
        """A JSON-able description of the source (a drive train is stored whole)."""
        return dict(self._spec)

    # ----- prediction ---------------------------------------------------------------------
    def predict(
        self, series: MeasurementSeries, channels: Sequence[str] | None = None
    ) -> pd.DataFrame:
        """The mechanistic values as a labelled frame, as every model's ``predict`` gives it:
        the time (s; the column named as the data file named it, else ``time``), one column
        per channel (default: the series' output channels), ``record`` for a series of several
        records; ``frame.attrs["units"]`` holds the channel units. :meth:`predict_values`
        gives the same values as an array."""

        values = self.predict_values(series, channels)
        names = tuple(series.channels if channels is None else channels)
        frame = pd.DataFrame({series.time_column: series.time_s})
        for j, name in enumerate(names):
            frame[name] = values[:, j]
        if series.n_records > 1:
            frame["record"] = series.record_ids()
        frame.attrs["units"] = {name: series.unit(name) for name in names}
        frame.attrs["model"] = self.name
        return frame

    def predict_values(
        self, series: MeasurementSeries, channels: Sequence[str] | None = None
    ) -> np.ndarray:
        """The mechanistic values of ``channels`` (default: the series' output channels) on
        the series' time grid, ``(n, len(channels))``, float64, record by record.

        Raises :class:`DataError` where a file does not cover a record, lacks a channel, or a
        source returns the wrong shape or non-finite values.
        """
        if not isinstance(series, MeasurementSeries):
            raise DataError(f"expected a MeasurementSeries, got {type(series).__name__}")
        names = tuple(series.channels if channels is None else channels)
        if self._array is not None:
            return self._aligned_array(series, names)
        bounds = series.record_bounds()
        if self._tables and len(self._tables) != len(bounds):
            raise self._count_error(len(bounds), "the records", record_names(series))
        parts = [self._record(series, k, a, b, names) for k, (a, b) in enumerate(bounds)]
        return np.vstack(parts) if parts else np.zeros((0, len(names)))

    def values_at(
        self,
        time_s: np.ndarray,
        channels: Sequence[str],
        inputs: Mapping[str, np.ndarray] | None = None,
    ) -> np.ndarray:
        """Values of ``channels`` at arbitrary time stamps (s), for sources that can be
        evaluated one time stamp at a time: files, tables and ``f(time_s[, inputs])``
        callables (a drive-train simulation needs the whole record). A file stamped with
        dates is read in seconds from its first stamp."""
        names, time_s = tuple(channels), np.asarray(time_s, dtype=np.float64)
        where = f"mechanistic source {self.name}"
        if self._tables:
            if len(self._tables) > 1:
                raise DataError("several simulator files: evaluate them record by record",
                                source=where)  # fmt: skip
            return interpolate(self._tables[0], time_s, self._table_columns(names), names, where)
        if self._record_fn is None or self._spec["kind"] != "callable":
            raise DataError(f"{where} cannot be evaluated at single time stamps",
                            fix="pass a table or a callable of time")  # fmt: skip
        out = self._record_fn(time_s, dict(inputs or {}), names, {})
        return check_values(out, len(time_s), names, self.channels, where)

    def _record(
        self, series: MeasurementSeries, k: int, a: int, b: int, names: tuple[str, ...]
    ) -> np.ndarray:
        where = f"mechanistic source {self.name}"
        if series.n_records > 1:
            where += f" (record {k + 1})"
        time_s = series.time_s[a:b]
        if self._tables:
            table = self._aligned(series, k)
            return interpolate(table, time_s, self._table_columns(names), names, where)
        if self._series_fn is not None:
            out = self._series_fn(series.slice(a, b))
        else:
            assert self._record_fn is not None
            inputs = {name: v[a:b] for name, v in series.inputs.items()}
            units = {c: series.unit(c) for c in names}
            out = self._record_fn(time_s, inputs, names, units)
        return check_values(out, b - a, names, self.channels, where)

    def _aligned(self, series: MeasurementSeries, k: int) -> Table:
        """Table ``k`` on the seconds of record ``k`` of ``series`` (a table stamped with
        dates moved by its first stamp against the record's file's)."""
        table = self._tables[k]
        if table.start is None:  # in seconds: as it is (no names needed)
            return table
        return table.in_frame_of(record_start(series, k), self._table_names[k],
                                 record_names(series)[k])  # fmt: skip

    def _stamps_note(self, series: MeasurementSeries, k: int) -> str:
        """`` (stamped from ..., the record from ...)`` for a table stamped with dates."""
        start = self._tables[k].start
        return "" if start is None else (f" (stamped from {start}, the record from "
                                         f"{record_start(series, k)})")  # fmt: skip

    def _table_columns(self, names: tuple[str, ...]) -> list[str]:
        return [self._columns.get(n, n).lower() for n in names]

    def _aligned_array(self, series: MeasurementSeries, names: tuple[str, ...]) -> np.ndarray:
        assert self._array is not None
        if self._array.shape[0] != len(series):
            raise DataError(
                f"the mechanistic array has {self._array.shape[0]} rows but the series has "
                f"{len(series)} samples",
                source="mechanistic array",
                fix="pass an array aligned with the series, or a table with a time column",
            )
        return check_values(self._array, len(series), names, self.channels, "mechanistic array")

    def __repr__(self) -> str:
        return f"MechanisticModel({self.name!r})"


def as_mechanistic(source: object) -> MechanisticModel:
    """``source`` as a :class:`MechanisticModel` (a drive train is simulated; text is read
    as ``--mechanistic`` reads it: ``preset``, ``config:FILE``, ``FILE[,FILE...]``, as
    ``dt.fit`` takes it)."""
    if isinstance(source, MechanisticModel):
        return source
    if isinstance(source, str):
        return MechanisticModel.from_option(source)
    from drafttwin.mechanics import DriveTrain

    if isinstance(source, DriveTrain):
        return MechanisticModel.from_train(source)
    return MechanisticModel(source)


def spec_cutoff_hz(spec: Mapping[str, Any] | None) -> float | None:
    """The reduction cut-off (Hz) a stored drive-train source was simulated with, ``None`` for
    the full train (and for model files written before the field existed: they were full)."""
    value = (spec or {}).get("cutoff_hz")
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0 < value < np.inf:
        raise DataError(f"the stored physics' cutoff_hz={value!r} is not a positive frequency",
                        fix="refit the model (the model file was edited or damaged)")  # fmt: skip
    return float(value)


def _reduced(train: DriveTrain, cutoff_hz: float | None) -> DriveTrain:
    from drafttwin.mechanics import reduce

    return train if cutoff_hz is None else reduce(train, cutoff_hz)


def _reduction_spec(train: DriveTrain) -> dict[str, float]:
    return {} if train.reduction is None else {"cutoff_hz": train.reduction.cutoff_hz}


def _reduction_label(train: DriveTrain) -> str:
    red = train.reduction
    return "" if red is None else f" (reduced: couplings above {red.cutoff_hz:g} Hz rigid)"


def describe_spec(spec: Mapping[str, Any] | None) -> str:
    """How a stored source reads in a message (``simulator output file a.csv``...)."""
    if not spec:
        return "no mechanistic source"
    kind = spec.get("kind")
    if kind == "file":
        return "the simulator output file(s) " + ", ".join(spec.get("paths", []))
    return {"callable": "a Python callable", "series-callable": "a Python function",
            "table": "a DataFrame", "array": "an array"}.get(str(kind), str(kind))  # fmt: skip
