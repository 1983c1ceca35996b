"""What a model predicts from what: the task, its channels, and the rows it may use.

A :class:`Task` is one value object shared by every estimator:

* ``kind="prediction"``: one-step-ahead prediction; row ``T`` uses measured outputs up to
  ``T - horizon`` only;
* ``kind="simulation"``: free run; only the first ``init_samples`` measured rows of each record
  are used (:func:`blank_after_init` removes every later measured output before any model code
  sees the series);
* ``outputs``: the output channels (``None``: the series' channels at fit time);
* ``inputs``: exogenous input channels fed to the learned parts (set-points, a drive voltage),
  known at every row in both tasks.

The helpers below turn a series into the arrays the models use: input matrices, the blanked
series of a simulation, per-record starts.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import ConfigError, DataError

TASKS = ("prediction", "simulation")
"""Accepted values of :attr:`Task.kind`."""


def _names(value: Any, what: str, *, allow_empty: bool) -> tuple[str, ...]:
    if isinstance(value, str) or not isinstance(value, Sequence):
        raise ConfigError(f"{what} must be a list of channel names, got {value!r}",
                          fix=f"pass {what} as a tuple of names, e.g. ('y',)")  # fmt: skip
    names = tuple(value)
    if not names and not allow_empty:
        raise ConfigError(f"{what} is empty", fix=f"name at least one channel in {what}")
    if not all(isinstance(s, str) and s for s in names) or len(set(names)) != len(names):
        raise ConfigError(f"{what} {list(names)} must be distinct, non-empty names",
                          fix=f"list each channel once in {what}")  # fmt: skip
    return names


def _positive_int(value: Any, what: str, *, allow_none: bool) -> None:
    if value is None and allow_none:
        return
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise ConfigError(f"{{{what}}} is invalid", terms={what: value},
                          fix=f"{{{what}:name}} must be an integer >= 1")  # fmt: skip


@dataclass(frozen=True)
class Task:
    """The prediction task of an estimator (checked on construction).

    Attributes:
        kind: ``"prediction"`` (one step ahead) or ``"simulation"`` (free run).
        horizon: prediction only: row ``T`` uses measurements up to ``T - horizon``.
        outputs: output channel names; ``None`` = the series' channels when fitting.
        inputs: exogenous input channels (in ``series.inputs``) the networks see.
        init_samples: simulation only: measured rows at the start of each record that a free
            run may use (``None``: the model's longest window).
    """

    kind: str = "prediction"
    horizon: int = 1
    outputs: tuple[str, ...] | None = None
    inputs: tuple[str, ...] = field(default=())
    init_samples: int | None = None

    def __post_init__(self) -> None:
        if self.kind not in TASKS:
            raise ConfigError(f"unknown task {self.kind!r}", fix=f"use one of {', '.join(TASKS)}")
        _positive_int(self.horizon, "horizon", allow_none=False)
        _positive_int(self.init_samples, "init_samples", allow_none=True)
        if self.outputs is not None:
            object.__setattr__(self, "outputs", _names(self.outputs, "outputs", allow_empty=False))
        object.__setattr__(self, "inputs", _names(self.inputs, "inputs", allow_empty=True))
        clash = set(self.inputs) & set(self.outputs or ())
        if clash:
            raise ConfigError(f"channel(s) {sorted(clash)} are both inputs and outputs",
                              fix="an exogenous input must not be an output channel")  # fmt: skip
        if self.kind == "simulation" and self.horizon != 1:
            raise ConfigError(
                "{horizon} is only meaningful for one-step prediction, not {task}",
                terms={"horizon": self.horizon, "task": self.kind},
                fix="leave {horizon:name} at 1 for a simulation (a free run predicts every row)",
            )
        if self.kind == "prediction" and self.init_samples is not None:
            raise ConfigError(
                "{init_samples} is only meaningful for a simulation, not {task}",
                terms={"init_samples": self.init_samples, "task": self.kind},
                fix="leave {init_samples:name} out for one-step prediction (it uses all history)",
            )

    @property
    def simulation(self) -> bool:
        return self.kind == "simulation"

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["outputs"] = None if self.outputs is None else list(self.outputs)
        out["inputs"] = list(self.inputs)
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Task:
        fields = dict(data)
        if fields.get("outputs") is not None:
            fields["outputs"] = tuple(fields["outputs"])
        fields["inputs"] = tuple(fields.get("inputs") or ())
        return cls(**fields)

    def replace(self, **changes: Any) -> Task:
        return Task(**{**asdict(self), **changes})


def init_rows(task: Task, *windows: int) -> int:
    """Measured rows a simulation may use: ``init_samples``, else the longest window."""
    if task.init_samples is not None:
        return int(task.init_samples)
    return max((int(w) for w in windows), default=1)


def check_windows(task: Task, **windows: int) -> None:
    """Refuse a simulation whose input windows are longer than its measured start."""
    if not task.simulation or task.init_samples is None:
        return
    for name, w in windows.items():
        if w > task.init_samples:
            raise ConfigError(
                f"{{{name}}} is longer than the {{init_samples:value}} measured rows a "
                "simulation may use ({init_samples:name})",
                terms={name: w, "init_samples": task.init_samples},
                fix=f"set {{init_samples:name}} to {w} or more, or {{{name}:name}} to "
                f"{task.init_samples} or less",
            )


def input_matrix(series: MeasurementSeries, names: Sequence[str]) -> np.ndarray:
    """Exogenous inputs ``(n, len(names))`` from ``series.inputs`` (their own units)."""
    cols = []
    for name in names:
        if name not in series.inputs:
            raise DataError(
                f"the series has no input channel {name!r} (inputs: "
                f"{', '.join(sorted(series.inputs)) or 'none'})",
                fix="read the file with that column among --inputs, or drop it from the "
                "model's inputs",
            )
        cols.append(np.asarray(series.inputs[name], dtype=np.float64))
    return np.column_stack(cols) if cols else np.zeros((len(series), 0))


def blank_after_init(series: MeasurementSeries, init: int) -> MeasurementSeries:
    """The series with every measured output after the first ``init`` rows of each record set
    to NaN: what a simulation may see (inputs stay: they are known in advance)."""
    values = np.array(series.values, dtype=np.float64, copy=True)
    for a, b in series.record_bounds():
        values[a + init : b] = np.nan
    return series.with_values(values)


__all__ = [
    "TASKS",
    "Task",
    "blank_after_init",
    "check_windows",
    "init_rows",
    "input_matrix",
]
