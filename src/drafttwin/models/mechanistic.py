"""The mechanistic prediction as a pluggable source.

A mechanistic model depends only on machine settings, so its prediction for any sample time is
known in advance and may be used up to and including the target time (SPEC section 2). Sources:

* a Python callable ``f(time_s) -> (n, 4)`` rpm,
* a CSV/Parquet file from any external simulator with a ``time`` column (seconds) and one
  column per roller (rpm), linearly interpolated onto the measurement time grid,
* a ``pandas.DataFrame`` with the same columns,
* a precomputed ``(n, 4)`` array aligned row by row with the series,
* the built-in drive-train preset (:meth:`MechanisticModel.from_preset`),
* a function of the whole series (:meth:`MechanisticModel.from_series_function`), for a
  simulation driven by the series' exogenous inputs (e.g. the EMPS drive voltage).

Sources of other output channels than the four rollers (e.g. a position in m) name them with
``channels=(...)``; the estimators check that they match their ``outputs``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from drafttwin import ROLLERS
from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import DataError

TIME_COLUMNS = ("time", "time_s", "t")
"""Accepted names (case-insensitive) of the time column of a simulator output file."""

MechanisticSource = Callable[[np.ndarray], np.ndarray] | str | Path | np.ndarray | pd.DataFrame


class MechanisticModel:
    """Mechanistic roller-speed prediction from a callable, a file, a table or an array.

    Args:
        source: see the module docstring.
        columns: optional mapping ``roller -> column name`` for files and tables whose roller
            columns are not called front/second/third/back.
        name: a label for reports (defaults to a description of the source).
        channels: names of the predicted channels (default: the four rollers), in column
            order; files and tables are read by these names.
    """

    def __init__(
        self,
        source: MechanisticSource,
        *,
        columns: Mapping[str, str] | None = None,
        name: str | None = None,
        channels: Sequence[str] | None = None,
    ) -> None:
        self._spec: dict[str, Any]
        self._table: tuple[np.ndarray, np.ndarray] | None = None
        self._func: Callable[[np.ndarray], np.ndarray] | None = None
        self._series_func: Callable[[MeasurementSeries], np.ndarray] | None = None
        self._array: np.ndarray | None = None
        self.channels: tuple[str, ...] = ROLLERS if channels is None else tuple(channels)
        label: str | None = None
        if isinstance(source, str | Path):
            path = Path(source)
            frame = _read_table(path)
            self._table = _table_arrays(frame, columns, source=str(path), channels=self.channels)
            self._spec = {"kind": "file", "path": str(path.resolve())}
            label = str(path)
        elif isinstance(source, pd.DataFrame):
            self._table = _table_arrays(
                source, columns, source="mechanistic table", channels=self.channels
            )
            self._spec = {"kind": "table"}
        elif isinstance(source, np.ndarray):
            self._array = _check_rpm(source, None, "mechanistic array", self.channels)
            self._spec = {"kind": "array"}
        elif callable(source):
            self._func = source
            self._spec = {"kind": "callable"}
        else:
            raise DataError(
                f"cannot use a {type(source).__name__} as a mechanistic source",
                fix="pass a callable f(time_s) -> (n, 4) rpm, a CSV/Parquet path, a DataFrame "
                "or an (n, 4) array",
            )
        if self.channels != ROLLERS:
            self._spec["channels"] = list(self.channels)
        self.name = name or label or self._spec["kind"]

    @classmethod
    def from_series_function(
        cls,
        func: Callable[[MeasurementSeries], np.ndarray],
        *,
        channels: Sequence[str] | None = None,
        name: str | None = None,
    ) -> MechanisticModel:
        """A source computed from the whole series, ``func(series) -> (n, channels)``.

        For a simulation driven by the series' exogenous inputs (``series.inputs``). In
        simulation mode the estimators pass a series whose outputs after the initialisation
        window are NaN, so such a function can use at most the initial measured state.
        Not stored in model files (pass it again to ``predict``).
        """
        model = cls.__new__(cls)
        model._table, model._func, model._array = None, None, None
        model._series_func = func
        model.channels = ROLLERS if channels is None else tuple(channels)
        model._spec = {"kind": "series-callable"}
        if model.channels != ROLLERS:
            model._spec["channels"] = list(model.channels)
        model.name = name or "series-callable"
        return model

    @classmethod
    def from_preset(cls, preset: str = "fa320a") -> MechanisticModel:
        """The built-in torsional drive-train model ``preset`` simulated on the series' grid."""
        from drafttwin import mechanics  # heavy (numba); imported only when used

        train = mechanics.DriveTrain.preset(preset)
        cache: dict[bytes, np.ndarray] = {}

        def simulate(time_s: np.ndarray) -> np.ndarray:
            key = np.ascontiguousarray(time_s, dtype=np.float64).tobytes()
            if key not in cache:
                cache.clear()
                cache[key] = np.asarray(mechanics.simulate_on_grid(train, time_s), np.float64)
            return cache[key]

        model = cls(simulate, name=f"preset {preset}")
        model._spec = {"kind": "preset", "name": preset}
        return model

    @classmethod
    def from_spec(cls, spec: Mapping[str, Any] | None) -> MechanisticModel | None:
        """Rebuild a source recorded by :meth:`spec` when possible (preset or file), else
        ``None`` (callables, tables and arrays are not stored in model files)."""
        if not spec:
            return None
        if spec.get("kind") == "preset":
            return cls.from_preset(str(spec["name"]))
        if spec.get("kind") == "file" and Path(str(spec["path"])).is_file():
            return cls(str(spec["path"]), channels=spec.get("channels"))
        return None

    def spec(self) -> dict[str, Any]:
        """A JSON-able description of the source (kind, plus preset name or file path)."""
        return dict(self._spec)

    def predict(self, series: MeasurementSeries | np.ndarray) -> np.ndarray:
        """Mechanistic speeds in rpm on the series' time grid, shape ``(n, 4)``, float64.

        ``series`` may also be a plain array of sample times in seconds (not for a
        :meth:`from_series_function` source). Raises :class:`DataError` if a file/table does
        not cover the time span or a source returns the wrong shape or non-finite values.
        """
        time_s = series.time_s if isinstance(series, MeasurementSeries) else np.asarray(series)
        time_s = np.asarray(time_s, dtype=np.float64)
        where = f"mechanistic source {self.name}"
        if self._series_func is not None:
            if not isinstance(series, MeasurementSeries):
                raise DataError(
                    "this mechanistic source is a function of the whole series",
                    source=where,
                    fix="pass the MeasurementSeries, not an array of sample times",
                )
            return _check_rpm(self._series_func(series), time_s.shape[0], where, self.channels)
        if self._array is not None:
            if self._array.shape[0] != time_s.shape[0]:
                raise DataError(
                    f"the mechanistic array has {self._array.shape[0]} rows but the series has "
                    f"{time_s.shape[0]} samples",
                    source="mechanistic array",
                    fix="pass an array aligned with the series, or a table with a time column",
                )
            return self._array.copy()
        if self._table is not None:
            return _interpolate(*self._table, time_s, self.name)
        assert self._func is not None
        return _check_rpm(self._func(time_s), time_s.shape[0], where, self.channels)

    def __repr__(self) -> str:
        return f"MechanisticModel({self.name!r})"


def _check_rpm(
    values: object, n: int | None, source: str, channels: tuple[str, ...] = ROLLERS
) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != len(channels) or (n is not None and arr.shape[0] != n):
        want = f"({n if n is not None else 'n'}, {len(channels)})"
        what = "roller" if channels == ROLLERS else "channel"
        raise DataError(
            f"expected speeds of shape {want} (one column per {what}: {', '.join(channels)}), "
            f"got shape {arr.shape}",
            source=source,
            fix=f"return/provide one column per {what} in the order {', '.join(channels)}",
        )
    bad = ~np.isfinite(arr)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise DataError(
            "mechanistic speeds must be finite",
            source=source,
            where=f"row {row}, channel {channels[col]}",
            fix="fill or drop the missing simulator output",
        )
    return arr


def _read_table(path: Path) -> pd.DataFrame:
    if not path.is_file():
        raise DataError("file not found", source=path, fix="check the path of the simulator output")
    suffix = path.suffix.lower()
    try:
        if suffix in (".parquet", ".pq"):
            return pd.read_parquet(path)
        if suffix in (".csv", ".txt"):
            return pd.read_csv(path)
    except (ValueError, OSError) as exc:
        raise DataError(f"cannot read the file ({exc})", source=path) from exc
    raise DataError(
        f"unsupported file type {suffix or '(none)'}",
        source=path,
        fix="write the simulator output as .csv or .parquet",
    )


def _find_column(frame: pd.DataFrame, names: tuple[str, ...], source: str, what: str) -> str:
    lower = {str(c).strip().lower(): c for c in frame.columns}
    for name in names:
        if name.lower() in lower:
            return str(lower[name.lower()])
    raise DataError(
        f"no {what} column (looked for {', '.join(names)})",
        source=source,
        where=f"columns {list(map(str, frame.columns))}",
        fix=f"add a {what} column or map it with columns={{...}}",
    )


def _numeric(frame: pd.DataFrame, column: str, source: str) -> np.ndarray:
    values = pd.to_numeric(frame[column], errors="coerce").to_numpy(dtype=np.float64)
    bad = ~np.isfinite(values)
    if bad.any():
        row = int(np.argmax(bad))
        raise DataError(
            f"non-numeric or missing value {frame[column].iloc[row]!r}",
            source=source,
            where=f"row {row + 2} (data row {row}), column {column!r}",
            fix="the simulator output must be complete numbers (time in seconds, speeds in rpm)",
        )
    return values


def _table_arrays(
    frame: pd.DataFrame,
    columns: Mapping[str, str] | None,
    source: str,
    channels: tuple[str, ...] = ROLLERS,
) -> tuple[np.ndarray, np.ndarray]:
    if len(frame) < 2:
        raise DataError(f"{len(frame)} row(s); need at least 2", source=source)
    time_col = _find_column(frame, TIME_COLUMNS, source, "time")
    mapping = dict(columns or {})
    what = "roller" if channels == ROLLERS else "channel"
    roller_cols = [
        _find_column(frame, (mapping.get(r, r),), source, f"{what} {r!r}") for r in channels
    ]
    time_s = _numeric(frame, time_col, source)
    steps = np.diff(time_s)
    if (steps <= 0).any():
        row = int(np.argmax(steps <= 0)) + 1
        raise DataError(
            "time is not strictly increasing",
            source=source,
            where=f"data row {row}, column {time_col!r}",
            fix="sort the simulator output by time and drop duplicate times",
        )
    rpm = np.column_stack([_numeric(frame, c, source) for c in roller_cols])
    return time_s, rpm


def _interpolate(
    table_t: np.ndarray, table_rpm: np.ndarray, time_s: np.ndarray, source: str
) -> np.ndarray:
    """Linear interpolation of the table onto ``time_s``; refuses extrapolation."""
    if time_s.size == 0:
        return np.zeros((0, table_rpm.shape[1]))
    tol = 1e-6 * float(np.median(np.diff(table_t)))
    if time_s.min() < table_t[0] - tol or time_s.max() > table_t[-1] + tol:
        raise DataError(
            f"the mechanistic output covers {table_t[0]:g} s to {table_t[-1]:g} s but the series "
            f"spans {time_s.min():g} s to {time_s.max():g} s",
            source=source,
            fix="simulate over the whole measurement span (same time origin, in seconds)",
        )
    clipped = np.clip(time_s, table_t[0], table_t[-1])
    return np.column_stack(
        [np.interp(clipped, table_t, table_rpm[:, j]) for j in range(table_rpm.shape[1])]
    )
