"""Single models: the mechanistic baseline, persistence, and the GRU/LSTM data-driven models.

The data-driven models see a window of past measured speeds of all four rollers jointly,
rows ``T-h-W+1 .. T-h`` for target row ``T`` (``W`` = window, ``h`` = horizon), min-max scaled
with a scaler fitted on the training part only, and predict the four speeds at ``T``. Optional
exogenous ``inputs`` (set-point channels) join the window as extra channels. With
``task="simulation"`` they become NARX models run free from their own outputs
(:mod:`drafttwin.models.simulation`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from drafttwin.data.scaling import MinMaxScaler
from drafttwin.data.series import MeasurementSeries
from drafttwin.evaluation.metrics import persistence_forecast
from drafttwin.models import simulation as sim
from drafttwin.models.base import BaseModel, pack_module, unpack_module
from drafttwin.models.networks import RecurrentRegressor
from drafttwin.models.simulation import fit_scaler
from drafttwin.models.training import (
    FitProgress,
    History,
    TrainConfig,
    predict_network,
    train_network,
)
from drafttwin.models.windows import (
    causal_ffill,
    finite_rows,
    footprint_outside,
    gather_windows,
    target_rows,
)


class MechanisticBaseline(BaseModel):
    """The mechanistic model alone, as an estimator: ``predict`` returns its speeds (in both
    tasks: a mechanistic source is an open-loop simulation)."""

    needs_mechanistic = True

    def __init__(self, task: str = "prediction", outputs: tuple[str, ...] | None = None) -> None:
        self.task = task
        self.outputs = outputs

    @property
    def name(self) -> str:
        return "mechanistic"

    def _fit(self, series: MeasurementSeries, mech: np.ndarray | None, progress: FitProgress):
        return None

    def _predict(self, series: MeasurementSeries, mech: np.ndarray | None) -> np.ndarray:
        assert mech is not None
        return np.asarray(mech, dtype=np.float64).copy()


class PersistenceModel(BaseModel):
    """Naive forecast: the speed at ``T`` is the last measured speed at or before ``T-h``
    (simulation: the last measured value of the initialisation window, held)."""

    def __init__(
        self,
        horizon: int = 1,
        task: str = "prediction",
        outputs: tuple[str, ...] | None = None,
        init_samples: int | None = None,
    ) -> None:
        self.horizon = horizon
        self.task = task
        self.outputs = outputs
        self.init_samples = init_samples

    @property
    def name(self) -> str:
        return "persistence"

    def _fit(self, series: MeasurementSeries, mech: np.ndarray | None, progress: FitProgress):
        return None

    def _predict(self, series: MeasurementSeries, mech: np.ndarray | None) -> np.ndarray:
        if not sim.is_simulation(self):
            return persistence_forecast(series.values, self.horizon)
        init = sim.init_rows(self)
        out = np.full(series.values.shape, np.nan)
        if len(series) > init:
            out[init:] = causal_ffill(series.values[:init])[-1]
        return out


class _NeuralModel(BaseModel):
    """Shared pieces of the estimators that train networks."""

    trains_networks = True

    def _train_config(self, seed: int) -> TrainConfig:
        p = self.get_params()
        return TrainConfig(
            epochs=p["epochs"],
            batch_size=p["batch_size"],
            lr=float(p["lr"]),
            patience=p["patience"],
            val_fraction=float(p["val_fraction"]),
            clip_norm=p["clip_norm"],
            seed=seed,
            device=p["device"],
            stride=p.get("stride", 1),
        )


class _RecurrentModel(_NeuralModel):
    """GRU/LSTM regressor on windows of past measured speeds (all rollers jointly)."""

    cell = "gru"

    def __init__(
        self,
        window: int = 20,
        hidden: int = 48,
        layers: int = 2,
        dropout: float = 0.1,
        lr: float = 2e-3,
        batch_size: int = 64,
        epochs: int = 30,
        patience: int | None = 5,
        val_fraction: float = 0.2,
        clip_norm: float | None = 1.0,
        skip: bool = True,
        horizon: int = 1,
        seed: int = 0,
        device: str = "auto",
        quiet: bool = False,
        task: str = "prediction",
        outputs: tuple[str, ...] | None = None,
        inputs: tuple[str, ...] = (),
        init_samples: int | None = None,
        stride: int = 1,
    ) -> None:
        self.window = window
        self.hidden = hidden
        self.layers = layers
        self.dropout = dropout
        self.lr = lr
        self.batch_size = batch_size
        self.epochs = epochs
        self.patience = patience
        self.val_fraction = val_fraction
        self.clip_norm = clip_norm
        self.skip = skip
        self.horizon = horizon
        self.seed = seed
        self.device = device
        self.quiet = quiet
        self.task = task
        self.outputs = outputs
        self.inputs = inputs
        self.init_samples = init_samples
        self.stride = stride

    @property
    def name(self) -> str:
        return self.cell

    def _build(self) -> RecurrentRegressor:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(self.seed)
            return self._new_net()

    def _new_net(self) -> RecurrentRegressor:
        n_out, n_in = len(sim.output_names(self)), len(sim.input_names(self))
        simulating = sim.is_simulation(self)
        return RecurrentRegressor(
            (2 * n_out if simulating else n_out) + n_in,
            n_out,
            cell=self.cell,
            hidden=self.hidden,
            layers=self.layers,
            dropout=self.dropout,
            skip=self.skip and not simulating,  # NARX: the free run adds the change itself
        )

    def _inputs_of(self, series: MeasurementSeries) -> np.ndarray:
        return sim.input_matrix(series, sim.input_names(self))

    def _fit(self, series: MeasurementSeries, mech: np.ndarray | None, progress: FitProgress):
        self._fit_arrays(series.values, u=self._inputs_of(series), progress=progress)

    def _fit_arrays(
        self,
        y: np.ndarray,
        *,
        u: np.ndarray | None = None,
        exclude: tuple[int, int] | None = None,
        progress: FitProgress | None = None,
        stage: str | None = None,
    ) -> None:
        """Fit on measured speeds ``y`` (n, 4) rpm (or the output channels) and inputs ``u``
        (n, k). With ``exclude = (a, b)`` rows ``a..b-1`` are held out: blanked before scaling
        and filling, and no training window or target touches them (used for cross-fitting)."""
        u = np.zeros((len(y), 0)) if u is None else u
        if sim.is_simulation(self):
            sim.fit_narx(self, y, u, exclude=exclude, progress=progress,
                         stage=stage or f"{self.cell.upper()} (NARX)")  # fmt: skip
            return
        y_in = np.array(y, dtype=np.float64, copy=True)
        if exclude is not None:
            y_in[exclude[0] : exclude[1]] = np.nan
        scaler = fit_scaler(y_in, "measured speeds")
        u_scaler = self._fit_input_scaler(u, exclude)
        feats = np.hstack([scaler.transform(causal_ffill(y_in)), sim.scale_inputs(u_scaler, u)])
        targets = target_rows(len(y_in), self.window, self.horizon)
        if exclude is not None:
            targets = targets[footprint_outside(targets, self.window, self.horizon, exclude)]
        x = gather_windows(feats, targets, self.window, self.horizon)
        t = scaler.transform(y_in)[targets]
        ok = finite_rows(x, t)
        net = self._build()
        history = train_network(
            net, x[ok], t[ok], self._train_config(self.seed), progress=progress,
            stage=stage or self.cell.upper(),
        )  # fmt: skip
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
        self, y: np.ndarray, u: np.ndarray, segments: list[tuple[int, int]] | None = None
    ) -> np.ndarray:
        """NARX free runs (simulation mode) over ``segments`` (default: the whole series),
        including their measured initialisation rows; see :func:`simulation.run_narx`."""
        return sim.run_narx(self, np.asarray(y, np.float64), u, segments or [(0, len(y))])

    def _predict_arrays(self, y: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """Predictions (n, 4) rpm for measured speeds ``y`` (n, 4); NaN without full history.
        Simulation mode: the free run from the first ``init_samples`` rows (earlier rows NaN)."""
        y = np.asarray(y, dtype=np.float64)
        u = np.zeros((len(y), 0)) if u is None else u
        if sim.is_simulation(self):
            out = self._simulate_arrays(y, u)
            out[: sim.init_rows(self)] = np.nan
            return out
        out = np.full(y.shape, np.nan)
        feats = np.hstack(
            [self.scaler_.transform(causal_ffill(y)), sim.scale_inputs(self.input_scaler_, u)]
        )
        targets = target_rows(len(y), self.window, self.horizon)
        x = gather_windows(feats, targets, self.window, self.horizon)
        ok = finite_rows(x)
        if ok.any():
            pred = predict_network(self.net_, x[ok], device=self.device)
            out[targets[ok]] = self.scaler_.inverse_transform(pred)
        return out

    def _predict(self, series: MeasurementSeries, mech: np.ndarray | None) -> np.ndarray:
        return self._predict_arrays(series.values, self._inputs_of(series))

    def _get_state(self) -> tuple[dict[str, Any], dict[str, torch.Tensor]]:
        state: dict[str, Any] = {
            "scaler": self.scaler_.to_dict(),
            "history": self.history_.to_dict(),
        }
        if getattr(self, "input_scaler_", None) is not None:
            state["input_scaler"] = self.input_scaler_.to_dict()
        if sim.is_simulation(self):
            state["sim_scalers"] = sim.narx_state(self)
        return state, pack_module("net", self.net_)

    def _set_state(self, state: dict[str, Any], tensors: dict[str, torch.Tensor]) -> None:
        self.scaler_ = MinMaxScaler.from_dict(state["scaler"])
        self.history_ = History.from_dict(state["history"])
        inp = state.get("input_scaler")
        self.input_scaler_ = None if inp is None else MinMaxScaler.from_dict(inp)
        if "sim_scalers" in state:
            self.sim_scalers_ = sim.narx_restore(state["sim_scalers"])
        net = self._new_net()
        unpack_module("net", tensors, net)
        self.net_ = net


class GRUModel(_RecurrentModel):
    """The paper's data-driven model: a GRU on a window of the four measured speeds."""

    cell = "gru"


class LSTMModel(_RecurrentModel):
    """An LSTM data-driven model (same inputs as :class:`GRUModel`)."""

    cell = "lstm"
