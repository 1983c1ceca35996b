"""Streaming (one step at a time) prediction with a fitted model.

:class:`OnlinePredictor` keeps the short history a model needs (forward-filled speeds and
residuals, and the data-driven predictions it already made) and predicts one row per call with
one forward pass per network, instead of recomputing every window as :meth:`predict` does.
Its numbers equal ``model.predict`` on the same record up to float32 rounding of batched vs
single-window evaluation (well below 1e-3 rpm).

Protocol: ``forecast`` predicts the row ``horizon`` samples after the last observed one, from
observed rows only; ``observe`` appends a measurement (``NaN`` = missing sample).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import ConfigError, DataError
from drafttwin.models.estimators.base import BaseModel
from drafttwin.models.estimators.baselines import MechanisticBaseline, PersistenceModel
from drafttwin.models.estimators.datadriven import _RecurrentModel
from drafttwin.models.estimators.hybrid import _ResidualHybrid
from drafttwin.models.estimators.mdsl import MDSL
from drafttwin.models.estimators.windows import causal_ffill
from drafttwin.models.mechanistic import MechanisticModel
from drafttwin.models.training.compute import place, resolve_device


def _run(net: nn.Module, x: list[np.ndarray], extra: np.ndarray | None = None) -> np.ndarray:
    """One window ``x`` (rows, oldest first) through ``net``; returns float64 (outputs,)."""
    device = next(net.parameters()).device
    xt = torch.as_tensor(np.asarray(x, dtype=np.float32)[None], device=device)
    out: torch.Tensor
    with torch.inference_mode():
        if extra is None:
            out = net(xt)
        else:
            out = net(xt, torch.as_tensor(extra[None].astype(np.float32), device=device))
    return out[0].cpu().numpy().astype(np.float64)


class OnlinePredictor:
    """Step-by-step prediction with a fitted drafttwin model.

    Args:
        model: a fitted estimator (any of :func:`drafttwin.models.make_model`'s models).
        mechanistic: the mechanistic source for hybrids (else the one recorded in the model).
    """

    def __init__(self, model: BaseModel, mechanistic: object | None = None) -> None:
        model._check_fitted()
        if model.task.simulation or model.task.inputs:
            raise ConfigError(
                f"streaming supports task 'prediction' models without exogenous inputs; this "
                f"{model.name} has task {model.task.kind!r}, inputs {list(model.task.inputs)}",
                fix="use model.predict(series) for simulation runs and models with inputs",
            )
        self.model = model
        self.horizon = int(model.task.horizon)
        self.n_channels = len(model.channels_)
        self._mech: MechanisticModel | None = None
        if model.needs_mechanistic:
            mech = (
                mechanistic
                if mechanistic is not None
                else MechanisticModel.from_spec(model.mechanistic_spec_)
            )
            if mech is None:
                raise ConfigError(
                    f"the {model.name} model needs a mechanistic prediction",
                    fix="pass mechanistic=MechanisticModel(source)",
                )
            self._mech = mech if isinstance(mech, MechanisticModel) else MechanisticModel(mech)
            if self._mech.spec()["kind"] not in ("file", "table", "callable"):
                raise ConfigError(
                    f"a {self._mech.spec()['kind']} mechanistic source cannot be evaluated one "
                    "time stamp at a time",
                    fix="simulate the planned run once and pass it as a table: "
                    "MechanisticModel(DataFrame with time + channel columns)",
                )
        training = getattr(model, "training", None)
        for net in self._nets():
            place(net, resolve_device(training.device if training is not None else "cpu"))
        data_window = model._template().window if isinstance(model, MDSL) else 0
        keep = max(getattr(model, "window", 1), data_window + self.horizon)
        self._yf: deque[np.ndarray] = deque(maxlen=keep + 1)
        self._em: deque[np.ndarray] = deque(maxlen=keep + 1)
        self._ed: deque[np.ndarray] = deque(maxlen=keep + 1)
        self._pending: dict[int, np.ndarray] = {}
        self.n_observed = 0

    def _nets(self) -> list[nn.Module]:
        nets = [getattr(self.model, "net_", None)]
        data = getattr(self.model, "data_model_", None)
        nets.append(None if data is None else data.net_)
        return [n for n in nets if n is not None]

    # ----- feeding measurements -----------------------------------------------------
    def observe(self, time_s: float, values: Sequence[float] | np.ndarray,
                mechanistic_row: np.ndarray | None = None) -> None:  # fmt: skip
        """Append one measured row (time in s, one value per output channel; ``NaN`` =
        missing). ``mechanistic_row``: the mechanistic source's values at ``time_s`` when the
        caller has them already (the live twin steps the physics itself; finite, one per
        output channel), instead of asking the source again."""
        y = np.asarray(values, dtype=np.float64).reshape(-1)
        if y.shape != (self.n_channels,):
            raise DataError(
                f"a row needs {self.n_channels} values ({', '.join(self.model.channels_)}), "
                f"got {y.shape[0]}"
            )
        row = self.n_observed
        data = self._data_forecast(row) if isinstance(self.model, MDSL) else None
        self._yf.append(self._carry(self._yf, y))
        if self._mech is not None:
            m = self._mech_at(time_s, mechanistic_row)
            self._em.append(self._carry(self._em, y - m))
            if data is not None:
                self._ed.append(self._carry(self._ed, y - data))
        self.n_observed += 1
        self._pending = {k: v for k, v in self._pending.items() if k >= self.n_observed}

    def observe_series(self, series: MeasurementSeries) -> None:
        """Append a whole record (vectorised when nothing was observed yet)."""
        series = self.model._check_series(series)
        if series.n_records > 1:
            raise DataError("streaming follows one record", fix="observe one record at a time")
        if self.n_observed:
            for t, row in zip(series.time_s, series.values, strict=True):
                self.observe(float(t), row)
            return
        y = series.values
        keep = self._yf.maxlen or 1
        self._yf.extend(causal_ffill(y)[-keep:])
        if self._mech is not None:
            m = self._mech.predict_values(series, self.model.channels_)
            self._em.extend(causal_ffill(y - m)[-keep:])
            if isinstance(self.model, MDSL):
                d = self.model.data_model_._predict_arrays(y, np.zeros((len(y), 0)), (0,))
                self._ed.extend(causal_ffill(y - d)[-keep:])
        self.n_observed = len(series)

    @staticmethod
    def _carry(buffer: deque[np.ndarray], value: np.ndarray) -> np.ndarray:
        if not buffer:
            return value.copy()
        return np.where(np.isnan(value), buffer[-1], value)

    # ----- predicting ---------------------------------------------------------------
    def _data_forecast(self, target: int) -> np.ndarray:
        """The internal GRU's prediction for row ``target`` (cached), from rows <= target-h."""
        if target in self._pending:
            return self._pending[target]
        assert isinstance(self.model, MDSL)
        data = self.model.data_model_
        end = len(self._yf) + (target - self.n_observed) - self.horizon + 1  # exclusive
        start = end - data.window
        pred = np.full(self.n_channels, np.nan)
        if start >= 0 and end <= len(self._yf):
            rows = [self._yf[i] for i in range(start, end)]
            if np.isfinite(rows).all():
                scaled = data.scaler_.transform(np.asarray(rows))
                pred = data.scaler_.inverse_transform(_run(data.net_, list(scaled)))
        self._pending[target] = pred
        return pred

    def forecast(self, time_s: float, mechanistic_row: np.ndarray | None = None) -> np.ndarray:
        """Predicted values (channels,) for the row ``horizon`` samples after the last observed
        one, at time ``time_s`` (s); ``NaN`` while the history is too short.
        ``mechanistic_row`` as in :meth:`observe`."""
        step = self._prepare(time_s, mechanistic_row)
        if isinstance(step, np.ndarray):
            return step
        return step.finish(_run(step.net, list(step.x), step.extra))

    def _mech_at(self, time_s: float, row: np.ndarray | None) -> np.ndarray:
        """The mechanistic values at ``time_s``: ``row`` where the caller gave it (checked
        for shape and finiteness only: the source's own check costs 14 us a call, twice per
        sample and machine in the live twin), else the source's."""
        assert self._mech is not None
        if row is None:
            m: np.ndarray = self._mech.values_at(np.array([float(time_s)]), self.model.channels_)[0]
            return m
        if row.shape != (self.n_channels,) or not np.isfinite(row).all():
            raise DataError(f"the mechanistic row at {time_s:g} s is not {self.n_channels} "
                            f"finite values", fix="give one finite value per output channel")  # fmt: skip
        return row

    def _prepare(
        self, time_s: float, mechanistic_row: np.ndarray | None = None
    ) -> np.ndarray | _NetStep:
        """The forecast, or the network input it needs and how to finish it (so that
        :func:`forecast_many` can run one network pass for many predictors)."""
        target = self.n_observed - 1 + self.horizon
        model = self.model
        if isinstance(model, PersistenceModel):
            return self._yf[-1].copy() if self._yf else np.full(self.n_channels, np.nan)
        if isinstance(model, _RecurrentModel):
            return self._recurrent(model)
        assert self._mech is not None
        m = self._mech_at(time_s, mechanistic_row)
        if isinstance(model, MechanisticBaseline):
            return m
        if isinstance(model, _ResidualHybrid) and not model.correct_:
            return m  # validation kept the physics alone (as predict_values does)
        if isinstance(model, _ResidualHybrid):
            return self._hybrid(model, target, m)
        raise ConfigError(f"no online mode for {type(model).__name__}")

    def _recurrent(self, model: _RecurrentModel) -> np.ndarray | _NetStep:
        rows = list(self._yf)[-model.window :]
        if len(rows) < model.window or not np.isfinite(rows).all():
            return np.full(self.n_channels, np.nan)
        x = model.scaler_.transform(np.asarray(rows))
        return _NetStep(model.net_, x, None, model.scaler_.inverse_transform)

    def _hybrid(self, model: _ResidualHybrid, target: int, m: np.ndarray) -> np.ndarray | _NetStep:
        w = model.window
        scalers = model.scalers_
        if len(self._em) < w or (isinstance(model, MDSL) and len(self._ed) < w):
            return np.where(model.corrected_, np.nan, m)
        parts = [scalers["em"].transform(np.asarray(list(self._em)[-w:]))]
        extra = None
        if isinstance(model, MDSL):
            parts.append(scalers["ed"].transform(np.asarray(list(self._ed)[-w:])))
            if model.use_disagreement:
                extra = scalers["dis"].transform(self._data_forecast(target) - m)
        if not all(np.isfinite(p).all() for p in parts):
            return np.where(model.corrected_, np.nan, m)
        if extra is not None and not np.isfinite(extra).all():
            return np.where(model.corrected_, np.nan, m)
        corrected = model.corrected_  # the other channels: their physics, as predict_values

        def finish(e: np.ndarray) -> np.ndarray:
            return np.where(corrected, m + scalers["em"].inverse_transform(e), m)

        return _NetStep(model.net_, np.hstack(parts), extra, finish)


@dataclass
class _NetStep:
    """One pending network pass: input window ``x`` (rows, features), optional ``extra``, and
    ``finish`` mapping the network's output to the forecast."""

    net: nn.Module
    x: np.ndarray
    extra: np.ndarray | None
    finish: Callable[[np.ndarray], np.ndarray]


def forecast_many(
    predictors: Sequence[OnlinePredictor],
    times_s: Sequence[float],
    mechanistic_rows: Sequence[np.ndarray | None] | None = None,
) -> list[np.ndarray]:
    """``[p.forecast(t, row) ...]`` with one network pass per network for all predictors
    that share it (machines with one model): a batch of windows costs little more than one.
    Equal to the one-by-one forecasts up to float32 rounding of batched evaluation."""
    out: list[np.ndarray | None] = [None] * len(predictors)
    groups: dict[int, list[tuple[int, _NetStep]]] = {}
    rows = [None] * len(predictors) if mechanistic_rows is None else mechanistic_rows
    for i, (p, t, row) in enumerate(zip(predictors, times_s, rows, strict=True)):
        step = p._prepare(t, row)
        if isinstance(step, np.ndarray):
            out[i] = step
        else:
            groups.setdefault(id(step.net), []).append((i, step))
    for items in groups.values():
        net = items[0][1].net
        device = next(net.parameters()).device
        xt = torch.as_tensor(np.stack([s.x for _, s in items]).astype(np.float32), device=device)
        with torch.inference_mode():
            if items[0][1].extra is None:
                res = net(xt)
            else:
                ex = np.stack([np.asarray(s.extra) for _, s in items]).astype(np.float32)
                res = net(xt, torch.as_tensor(ex, device=device))
        res_np = res.cpu().numpy().astype(np.float64)
        for k, (i, s) in enumerate(items):
            out[i] = s.finish(res_np[k])
    return [o for o in out if o is not None]
