"""Single models: the mechanistic baseline, persistence, and the GRU/LSTM data-driven models.

The data-driven models see a window of past measured speeds of all four rollers jointly,
rows ``T-h-W+1 .. T-h`` for target row ``T`` (``W`` = window, ``h`` = horizon), min-max scaled
with a scaler fitted on the training part only, and predict the four speeds at ``T``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from drafttwin.data.scaling import MinMaxScaler
from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import DataError
from drafttwin.evaluation.metrics import persistence_forecast
from drafttwin.models.base import BaseModel, pack_module, unpack_module
from drafttwin.models.networks import RecurrentRegressor
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
    """The mechanistic model alone, as an estimator: ``predict`` returns its speeds."""

    needs_mechanistic = True

    def __init__(self) -> None:
        pass

    @property
    def name(self) -> str:
        return "mechanistic"

    def _fit(self, series: MeasurementSeries, mech: np.ndarray | None, progress: FitProgress):
        return None

    def _predict(self, series: MeasurementSeries, mech: np.ndarray | None) -> np.ndarray:
        assert mech is not None
        return np.asarray(mech, dtype=np.float64).copy()


class PersistenceModel(BaseModel):
    """Naive forecast: the speed at ``T`` is the last measured speed at or before ``T-h``."""

    def __init__(self, horizon: int = 1) -> None:
        self.horizon = horizon

    @property
    def name(self) -> str:
        return "persistence"

    def _fit(self, series: MeasurementSeries, mech: np.ndarray | None, progress: FitProgress):
        return None

    def _predict(self, series: MeasurementSeries, mech: np.ndarray | None) -> np.ndarray:
        return persistence_forecast(series.rpm, self.horizon)


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
        )


def fit_scaler(values: np.ndarray, what: str) -> MinMaxScaler:
    """A MinMaxScaler fitted on ``values``; a column without finite values is a DataError."""
    try:
        return MinMaxScaler().fit(values)
    except ValueError as exc:
        raise DataError(
            f"cannot scale the {what}: a column has no finite training value",
            fix="check the training part for rollers without any measurement",
        ) from exc


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

    @property
    def name(self) -> str:
        return self.cell

    def _build(self) -> RecurrentRegressor:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(self.seed)
            return self._new_net()

    def _new_net(self) -> RecurrentRegressor:
        return RecurrentRegressor(
            4,
            4,
            cell=self.cell,
            hidden=self.hidden,
            layers=self.layers,
            dropout=self.dropout,
            skip=self.skip,
        )

    def _fit(self, series: MeasurementSeries, mech: np.ndarray | None, progress: FitProgress):
        self._fit_arrays(series.rpm, progress=progress)

    def _fit_arrays(
        self,
        y: np.ndarray,
        *,
        exclude: tuple[int, int] | None = None,
        progress: FitProgress | None = None,
        stage: str | None = None,
    ) -> None:
        """Fit on measured speeds ``y`` (n, 4) rpm. With ``exclude = (a, b)`` rows ``a..b-1``
        are held out: blanked before scaling and filling, and no training window or target
        touches them (used for cross-fitting)."""
        y_in = np.array(y, dtype=np.float64, copy=True)
        if exclude is not None:
            y_in[exclude[0] : exclude[1]] = np.nan
        scaler = fit_scaler(y_in, "measured speeds")
        feats = scaler.transform(causal_ffill(y_in))
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

    def _predict_arrays(self, y: np.ndarray) -> np.ndarray:
        """Predictions (n, 4) rpm for measured speeds ``y`` (n, 4); NaN without full history."""
        y = np.asarray(y, dtype=np.float64)
        out = np.full(y.shape, np.nan)
        feats = self.scaler_.transform(causal_ffill(y))
        targets = target_rows(len(y), self.window, self.horizon)
        x = gather_windows(feats, targets, self.window, self.horizon)
        ok = finite_rows(x)
        if ok.any():
            pred = predict_network(self.net_, x[ok], device=self.device)
            out[targets[ok]] = self.scaler_.inverse_transform(pred)
        return out

    def _predict(self, series: MeasurementSeries, mech: np.ndarray | None) -> np.ndarray:
        return self._predict_arrays(series.rpm)

    def _get_state(self) -> tuple[dict[str, Any], dict[str, torch.Tensor]]:
        state = {"scaler": self.scaler_.to_dict(), "history": self.history_.to_dict()}
        return state, pack_module("net", self.net_)

    def _set_state(self, state: dict[str, Any], tensors: dict[str, torch.Tensor]) -> None:
        self.scaler_ = MinMaxScaler.from_dict(state["scaler"])
        self.history_ = History.from_dict(state["history"])
        net = self._new_net()
        unpack_module("net", tensors, net)
        self.net_ = net


class GRUModel(_RecurrentModel):
    """The paper's data-driven model: a GRU on a window of the four measured speeds."""

    cell = "gru"


class LSTMModel(_RecurrentModel):
    """An LSTM data-driven model (same inputs as :class:`GRUModel`)."""

    cell = "lstm"
