"""The data-driven models: GRU and LSTM on windows of past measured outputs.

Task ``prediction``: a window of the measured outputs (all channels jointly) at rows
``T-h-W+1 .. T-h`` (``W`` = window, ``h`` = horizon), min-max scaled with a scaler fitted on
the training part only, predicts the outputs at ``T``; exogenous ``inputs`` join the window as
extra channels. Task ``simulation``: a NARX model run free from its own outputs
(:mod:`drafttwin.models.estimators.narx`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from drafttwin.data.scaling import MinMaxScaler
from drafttwin.data.series import MeasurementSeries
from drafttwin.models.estimators import narx
from drafttwin.models.estimators.base import BaseModel, pack_module, unpack_module
from drafttwin.models.estimators.features import fit_scaler, scale_inputs
from drafttwin.models.estimators.networks import RecurrentRegressor
from drafttwin.models.estimators.task import Task, check_windows, input_matrix
from drafttwin.models.estimators.windows import (
    causal_ffill,
    finite_rows,
    footprint_outside,
    gather_windows,
    target_rows,
)
from drafttwin.models.training import (
    FitProgress,
    History,
    Training,
    predict_network,
    train_network,
)


class _NeuralModel(BaseModel):
    """Shared pieces of the estimators that train networks."""

    trains_networks = True
    window: int
    hidden: int
    layers: int
    dropout: float
    skip: bool | None
    training: Training
    seed: int
    quiet: bool

    def _device(self) -> str:
        return self.training.device


class _RecurrentModel(_NeuralModel):
    """GRU/LSTM regressor on windows of past measured outputs (all channels jointly).

    Args:
        window: input window, samples. hidden / layers: recurrent size. dropout: between
            layers.
        skip: task ``prediction``: the head predicts a change added to the last measured
            value (``None``: True; an untrained net is then persistence); ``False``: the
            plain regression of the paper. Must stay ``None`` in a simulation, where the NARX
            network always predicts the per-sample change.
        task: what is predicted from what (:class:`~drafttwin.models.estimators.task.Task`).
        training: how the network is trained (:class:`~drafttwin.models.training.Training`).
        seed: weight initialisation and batch order. quiet: no progress bar.
    """

    cell = "gru"

    def __init__(
        self,
        window: int = 20, hidden: int = 48, layers: int = 2, dropout: float = 0.1,
        skip: bool | None = None,
        task: Task = Task(), training: Training = Training(), seed: int = 0, quiet: bool = False,
    ) -> None:  # fmt: skip
        self._store_params(locals())

    @property
    def name(self) -> str:
        return self.cell

    def _check_params(self) -> None:
        super()._check_params()
        if self.task.simulation:
            self._refuse_for_task("skip", "the NARX network always predicts the change")
        check_windows(self.task, window=self.window)

    def _build(self, n_out: int) -> RecurrentRegressor:
        """A new network for ``n_out`` output channels, initialised from ``seed``."""
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(self.seed)
            return self._new_net(n_out)

    def _new_net(self, n_out: int) -> RecurrentRegressor:
        n_in = len(self.task.inputs)
        simulating = self.task.simulation
        return RecurrentRegressor(
            (2 * n_out if simulating else n_out) + n_in,
            n_out,
            cell=self.cell,
            hidden=self.hidden,
            layers=self.layers,
            dropout=self.dropout,
            skip=not simulating and self.skip is not False,
        )

    def _fit(
        self, series: MeasurementSeries, mech: np.ndarray | None, progress: FitProgress
    ) -> None:
        self._fit_arrays(series.values, input_matrix(series, self.task.inputs),
                         series.record_starts, progress=progress)  # fmt: skip

    def _fit_arrays(
        self,
        y: np.ndarray,
        u: np.ndarray,
        starts: tuple[int, ...],
        *,
        exclude: tuple[int, int] | None = None,
        progress: FitProgress | None = None,
        stage: str | None = None,
    ) -> None:
        """Fit on measured outputs ``y`` (n, channels) and inputs ``u`` (n, k) of records
        starting at ``starts``. With ``exclude = (a, b)`` rows ``a..b-1`` are held out:
        blanked before scaling and filling, and no training window or target touches them
        (used for cross-fitting)."""
        if self.task.simulation:
            narx.fit_narx(self, y, u, starts, exclude=exclude, progress=progress,
                          stage=stage or f"{self.cell.upper()} (NARX)")  # fmt: skip
            return
        y_in = np.array(y, dtype=np.float64, copy=True)
        if exclude is not None:
            y_in[exclude[0] : exclude[1]] = np.nan
        scaler = fit_scaler(y_in, "measured outputs")
        u_scaler = self._fit_input_scaler(u, exclude)
        feats = np.hstack([scaler.transform(causal_ffill(y_in, starts)),
                           scale_inputs(u_scaler, u, starts)])  # fmt: skip
        h = self.task.horizon
        targets = target_rows(len(y_in), self.window, h, starts)
        if exclude is not None:
            targets = targets[footprint_outside(targets, self.window, h, exclude)]
        x = gather_windows(feats, targets, self.window, h)
        t = scaler.transform(y_in)[targets]
        ok = finite_rows(x, t)
        net = self._build(y.shape[1])
        history = train_network(net, x[ok], t[ok], self.training, seed=self.seed,
                                progress=progress, stage=stage or self.cell.upper())  # fmt: skip
        self.scaler_, self.net_, self.history_ = scaler, net, history
        self.input_scaler_ = u_scaler

    def _fit_input_scaler(
        self, u: np.ndarray, exclude: tuple[int, int] | None
    ) -> MinMaxScaler | None:
        if u.shape[1] == 0:
            return None
        u_fit = np.array(u, dtype=np.float64, copy=True)
        if exclude is not None:
            u_fit[exclude[0] : exclude[1]] = np.nan
        return fit_scaler(u_fit, "inputs")

    def _simulate_arrays(
        self, y: np.ndarray, u: np.ndarray, segments: list[tuple[int, int]], init: int
    ) -> np.ndarray:
        """NARX free runs over ``segments``, their measured initialisation rows included."""
        return narx.run_narx(self, np.asarray(y, np.float64), u, segments, init)

    def _predict_arrays(
        self, y: np.ndarray, u: np.ndarray, starts: tuple[int, ...], init: int | None = None
    ) -> np.ndarray:
        """Predictions (n, channels) for measured outputs ``y``; NaN without full history.
        Simulation: each record's free run from its first ``init`` rows (those rows NaN)."""
        y = np.asarray(y, dtype=np.float64)
        if self.task.simulation:
            init = self._init_rows() if init is None else init
            bounds = _bounds(len(y), starts)
            out = self._simulate_arrays(y, u, bounds, init)
            for a, b in bounds:
                out[a : min(b, a + init)] = np.nan
            return out
        out = np.full(y.shape, np.nan)
        feats = np.hstack([self.scaler_.transform(causal_ffill(y, starts)),
                           scale_inputs(self.input_scaler_, u, starts)])  # fmt: skip
        h = self.task.horizon
        targets = target_rows(len(y), self.window, h, starts)
        x = gather_windows(feats, targets, self.window, h)
        ok = finite_rows(x)
        if ok.any():
            pred = predict_network(self.net_, x[ok], device=self._device())
            out[targets[ok]] = self.scaler_.inverse_transform(pred)
        return out

    def _predict(self, series: MeasurementSeries, mech: np.ndarray | None) -> np.ndarray:
        u = input_matrix(series, self.task.inputs)
        return self._predict_arrays(series.values, u, series.record_starts)

    def output_range(self) -> dict[str, tuple[float, float]]:
        self._check_fitted()
        sc = self.sim_scalers_["y"] if self.task.simulation else self.scaler_
        return {c: (float(lo), float(hi))
                for c, lo, hi in zip(self.channels_, sc.min_, sc.max_, strict=True)}  # fmt: skip

    def _get_state(self) -> tuple[dict[str, Any], dict[str, torch.Tensor]]:
        state: dict[str, Any] = {"history": self.history_.to_dict()}
        if self.task.simulation:
            state["sim_scalers"] = narx.narx_state(self.sim_scalers_)
        else:
            state["scaler"] = self.scaler_.to_dict()
            if self.input_scaler_ is not None:
                state["input_scaler"] = self.input_scaler_.to_dict()
        return state, pack_module("net", self.net_)

    def _set_state(self, state: dict[str, Any], tensors: dict[str, torch.Tensor]) -> None:
        self.history_ = History.from_dict(state["history"])
        if self.task.simulation:
            self.sim_scalers_ = narx.narx_restore(state["sim_scalers"])
        else:
            self.scaler_ = MinMaxScaler.from_dict(state["scaler"])
            inp = state.get("input_scaler")
            self.input_scaler_ = None if inp is None else MinMaxScaler.from_dict(inp)
        net = self._new_net(len(self.channels_))
        unpack_module("net", tensors, net)
        self.net_ = net


def _bounds(n: int, starts: tuple[int, ...]) -> list[tuple[int, int]]:
    ends = (*starts[1:], n)
    return [(a, b) for a, b in zip(starts, ends, strict=True) if b > a]


class GRUModel(_RecurrentModel):
    """The paper's data-driven model: a GRU on a window of the measured outputs."""

    cell = "gru"


class LSTMModel(_RecurrentModel):
    """An LSTM data-driven model (same inputs as :class:`GRUModel`)."""

    cell = "lstm"
