"""Hybrid models: the parallel hybrid and multi-model residual learning (MD-S-L and ablations).

Both correct the mechanistic prediction with a learned residual (paper eq. 15):
``yhat(T) = yhat_m(T) + ehat_m(T)``, where ``ehat_m(T)`` is predicted from residual channels up
to ``T-h`` only:

* parallel: the mechanistic residual ``e_m = y - yhat_m`` (4 channels) -> LSTM -> head;
* MD-S-L: ``e_m`` and the data-driven residual ``e_d = y - yhat_d`` (8 channels) -> SKNet ->
  LSTM -> head; MD-L drops the SKNet, MD-S drops the LSTM; with ``use_disagreement`` the
  current disagreement ``yhat_d(T) - yhat_m(T)`` (known at ``T``) enters the head too.

The data-driven residuals that train the residual model are out-of-sample: the GRU is
cross-fitted over contiguous blocks of the training part (fitted on the other blocks, with
every window touching the held-out block removed, then predicting the held-out block). At
prediction time the GRU fitted on the whole training part supplies ``yhat_d``.

Simulation mode (``task="simulation"``, see :mod:`drafttwin.models.simulation`): no measured
residual exists after the initialisation window, so the windows hold the exogenous inputs and
the simulated outputs instead: ``[yhat_m, dyhat_m]`` (parallel), plus the per-sample change
of the data-driven model's free run ``dyhat_d`` (MD-*), at rows ``T-W+1 .. T``. The target is the mechanistic
residual ``e_m(T)``, or with ``skip`` its per-sample change, accumulated from the measured
residual at the end of the initialisation window.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from drafttwin.data.scaling import MinMaxScaler
from drafttwin.data.series import MeasurementSeries
from drafttwin.models import simulation as sim
from drafttwin.models.base import pack_module, unpack_module
from drafttwin.models.datadriven import _NeuralModel, fit_scaler
from drafttwin.models.networks import ResidualNet
from drafttwin.models.training import FitProgress, History, predict_network, train_network
from drafttwin.models.windows import (
    causal_ffill,
    finite_rows,
    gather_windows,
    target_rows,
)

VARIANTS = ("md-s-l", "md-l", "md-s")
"""MD-S-L (SKNet + LSTM), MD-L (no SKNet), MD-S (no LSTM)."""


class _ResidualHybrid(_NeuralModel):
    """Residual correction of the mechanistic model from windows of residual channels
    (prediction) or of the inputs and simulated model outputs (simulation)."""

    needs_mechanistic = True
    use_sknet = False
    use_lstm = True

    # --- what each hybrid feeds the residual net -------------------------------------
    def _groups(
        self, y: np.ndarray, mech: np.ndarray, data: np.ndarray | None
    ) -> dict[str, np.ndarray]:
        """Raw channel groups (n, 4) each: ``em`` residual channels first (also the target)."""
        return {"em": y - mech}

    def _channel_groups(self) -> tuple[str, ...]:
        return ("em",)

    def _sim_channel_groups(self) -> tuple[str, ...]:
        """Simulation mode: the mechanistic output and its per-sample change."""
        return ("ym", "dym")

    def _extra_group(self) -> str | None:
        return None

    def _fit_data(self, y: np.ndarray, u: np.ndarray, progress: FitProgress) -> np.ndarray | None:
        return None

    def _predict_data(self, y: np.ndarray, u: np.ndarray) -> np.ndarray | None:
        return None

    # --- task plumbing ---------------------------------------------------------------
    def _channels(self) -> tuple[str, ...]:
        """Window channel groups in order (the ``em`` group first in prediction mode)."""
        base = self._sim_channel_groups() if sim.is_simulation(self) else self._channel_groups()
        return base + (("u",) if sim.input_names(self) else ())

    def _target_group(self) -> str:
        """``dem`` (the residual's per-sample change) for an accumulating simulation, else
        ``em``."""
        return "dem" if sim.is_simulation(self) and self.skip else "em"

    def _width(self, group: str) -> int:
        return len(sim.input_names(self) if group == "u" else sim.output_names(self))

    def _all_groups(
        self, y: np.ndarray, mech: np.ndarray, data: np.ndarray | None, u: np.ndarray
    ) -> dict[str, np.ndarray]:
        if not sim.is_simulation(self):
            groups = self._groups(y, mech, data)
        else:
            em = y - mech
            dem = np.full_like(em, np.nan)
            dem[1:] = em[1:] - em[:-1]
            groups = {"em": em, "dem": dem, "ym": mech, "dym": sim.increments(mech)}
            if data is not None:
                groups["dyd"] = sim.increments(data)
            if self._extra_group() is not None and data is not None:
                groups["dis"] = data - mech
        if u.shape[1]:
            groups["u"] = u
        return groups

    # --- shared machinery ----------------------------------------------------------
    def _new_net(self) -> ResidualNet:
        n_out = len(sim.output_names(self))
        return ResidualNet(
            sum(self._width(g) for g in self._channels()),
            n_out,
            n_extra=n_out if self._extra_group() else 0,
            use_sknet=self.use_sknet,
            use_lstm=self.use_lstm,
            sk_channels=getattr(self, "sk_channels", 24),
            hidden=self.hidden,
            layers=self.layers,
            dropout=self.dropout,
            skip=self.skip and not sim.is_simulation(self),
        )

    def _inputs(
        self, groups: dict[str, np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]:
        """Scaled windows, extras, scaled targets at T, and target rows. Prediction: rows
        ``T-h-W+1 .. T-h``; simulation: rows ``T-W+1 .. T`` (no measured channel in them)."""
        scaled = {k: self.scalers_[k].transform(v) for k, v in groups.items()}
        chans = np.hstack([causal_ffill(scaled[k]) for k in self._channels()])
        lag = 0 if sim.is_simulation(self) else self.horizon
        rows = target_rows(len(chans), self.window, lag)
        x = gather_windows(chans, rows, self.window, lag)
        key = self._extra_group()
        extra = None if key is None else scaled[key][rows].astype(np.float32)
        return x, extra, scaled[self._target_group()][rows], rows

    def _fit(self, series: MeasurementSeries, mech: np.ndarray | None, progress: FitProgress):
        assert mech is not None
        y = series.values
        u = sim.input_matrix(series, sim.input_names(self))
        data = self._fit_data(y, u, progress)
        groups = self._all_groups(y, mech, data, u)
        self.scalers_ = {k: fit_scaler(v, f"{k} channels") for k, v in groups.items()}
        x, extra, target, _ = self._inputs(groups)
        ok = finite_rows(x, target) if extra is None else finite_rows(x, target, extra)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(self.seed)
            net = self._new_net()
        extra_ok = None if extra is None else extra[ok]
        validate = None
        if self._target_group() == "dem":  # accumulating simulation: stop on the free-run drift
            validate = sim.drift_validator(
                x[ok], target[ok], extra_ok, float(self.val_fraction), int(self.stride)
            )
        self.history_ = train_network(
            net,
            x[ok],
            target[ok],
            self._train_config(self.seed),
            extra=extra_ok,
            progress=progress,
            stage=f"{self.name} residual model",
            validate=validate,
        )
        if self._target_group() == "dem":
            sim.debias_head(net, x[ok], target[ok], extra_ok, self.device)
        self.net_ = net

    def _predict(self, series: MeasurementSeries, mech: np.ndarray | None) -> np.ndarray:
        assert mech is not None
        y = series.values
        u = sim.input_matrix(series, sim.input_names(self))
        groups = self._all_groups(y, mech, self._predict_data(y, u), u)
        x, extra, _, rows = self._inputs(groups)
        ok = finite_rows(x) if extra is None else finite_rows(x, extra)
        pred = np.full(y.shape, np.nan)
        if ok.any():
            e = predict_network(
                self.net_, x[ok], extra=None if extra is None else extra[ok], device=self.device
            )
            pred[rows[ok]] = self.scalers_[self._target_group()].inverse_transform(e)
        if not sim.is_simulation(self):
            return mech + pred
        init = sim.init_rows(self)
        if self._target_group() == "dem":  # accumulate from the last measured residual
            anchor = causal_ffill(y[:init] - mech[:init])[-1]
            pred = sim.accumulate(anchor, pred, init)
        pred[:init] = np.nan
        return mech + pred

    def _get_state(self) -> tuple[dict[str, Any], dict[str, torch.Tensor]]:
        state = {
            "scalers": {k: s.to_dict() for k, s in self.scalers_.items()},
            "history": self.history_.to_dict(),
        }
        return state, pack_module("net", self.net_)

    def _set_state(self, state: dict[str, Any], tensors: dict[str, torch.Tensor]) -> None:
        self.scalers_ = {k: MinMaxScaler.from_dict(v) for k, v in state["scalers"].items()}
        self.history_ = History.from_dict(state["history"])
        net = self._new_net()
        unpack_module("net", tensors, net)
        self.net_ = net


class ParallelHybrid(_ResidualHybrid):
    """Parallel hybrid: an LSTM learns the mechanistic residual; output ``yhat_m + ehat_m``."""

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
        return "parallel"
