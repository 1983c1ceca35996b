"""The two models without learning: the mechanistic model alone, and persistence.

Persistence (``yhat(T) = y(T - h)``) is the naive forecast every comparison includes: on a
nearly constant signal a tiny relative error can mean no skill at all.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar

import numpy as np

from drafttwin.data.series import MeasurementSeries
from drafttwin.models.estimators.base import BaseModel
from drafttwin.models.estimators.task import Task
from drafttwin.models.estimators.windows import causal_ffill, record_ids
from drafttwin.models.training import FitProgress


def persistence_forecast(
    values: np.ndarray, horizon: int = 1, starts: Sequence[int] = (0,)
) -> np.ndarray:
    """The naive forecast ``yhat(T) = y(T - horizon)`` (the last measured value at or before
    ``T - horizon`` when samples are missing), record by record (``starts``: first row of each
    record); ``NaN`` where the record has no earlier value. Same units and shape as ``values``.
    """
    if horizon < 1:
        raise ValueError("horizon must be >= 1")
    y = np.asarray(values, dtype=np.float64)
    squeeze = y.ndim == 1
    y2 = y[:, None] if squeeze else y
    n = y2.shape[0]
    filled = causal_ffill(y2, starts)
    out = np.full_like(y2, np.nan)
    if n > horizon:
        out[horizon:] = filled[: n - horizon]
        rec = record_ids(n, starts)
        out[horizon:][rec[horizon:] != rec[: n - horizon]] = np.nan
    return out[:, 0] if squeeze else out


class _FixedRule(BaseModel):
    """A model that learns nothing: ``fit`` only records the channels, and ``task.inputs``
    must stay empty (``inputs_refused_because`` says why, in the error)."""

    registry_name: ClassVar[str]
    inputs_refused_because: ClassVar[str]

    def __init__(self, task: Task = Task()) -> None:
        self.task = task

    @property
    def name(self) -> str:
        return self.registry_name

    def _check_params(self) -> None:
        super()._check_params()
        _refuse_inputs(self, self.inputs_refused_because)

    def _fit(
        self, series: MeasurementSeries, mech: np.ndarray | None, progress: FitProgress
    ) -> None:
        return None


class MechanisticBaseline(_FixedRule):
    """The mechanistic model alone, as an estimator: ``predict`` returns the physics' values
    (in both tasks: a mechanistic source runs open loop from the machine's inputs; in a
    simulation the rows of the initialisation window are NaN, as for every model).

    ``task.inputs`` must stay empty: the physics reads the input channels its source maps
    (e.g. ``supply_hz``) from the series itself.
    """

    needs_mechanistic = True
    learns_from_mechanistic = False
    registry_name = "mechanistic"
    inputs_refused_because = "its source reads the input channels it maps from the series"

    def _predict(self, series: MeasurementSeries, mech: np.ndarray | None) -> np.ndarray:
        assert mech is not None
        out = np.asarray(mech, dtype=np.float64).copy()
        if self.task.simulation:
            _blank_init_rows(out, series, self._init_rows())
        return out


class PersistenceModel(_FixedRule):
    """Naive forecast: the value at ``T`` is the last measured value at or before
    ``T - horizon`` (simulation: the last measured value of each record's initialisation
    window, held)."""

    registry_name = "persistence"
    inputs_refused_because = "persistence repeats the last measured output"

    def _predict(self, series: MeasurementSeries, mech: np.ndarray | None) -> np.ndarray:
        starts = series.record_starts
        if not self.task.simulation:
            return persistence_forecast(series.values, self.task.horizon, starts)
        init = self._init_rows()
        out = np.full(series.values.shape, np.nan)
        for a, b in series.record_bounds():
            if b - a > init:
                out[a + init : b] = causal_ffill(series.values[a : a + init])[-1]
        return out


def _refuse_inputs(model: BaseModel, why: str) -> None:
    from drafttwin.errors import ConfigError

    if model.task.inputs:
        raise ConfigError(
            f"the {model.name} model takes no exogenous inputs ({why}); got inputs "
            f"{list(model.task.inputs)}",
            fix="leave the inputs empty for this model",
        )


def _blank_init_rows(values: np.ndarray, series: MeasurementSeries, init: int) -> None:
    for a, b in series.record_bounds():
        values[a : min(b, a + init)] = np.nan
