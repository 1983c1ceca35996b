"""Multi-model residual learning (MD-S-L) and its ablations MD-L and MD-S (paper section 3.2).

Inputs for target row ``T`` (horizon ``h``, residual window ``W``):

* residual channels ``e_m = y - yhat_m`` and ``e_d = y - yhat_d`` at rows ``T-h-W+1 .. T-h``;
* optionally (``use_disagreement``) the current disagreement ``yhat_d(T) - yhat_m(T)``.

``yhat_d`` comes from a GRU on measured speeds. While fitting, ``yhat_d`` over the training
part is cross-fitted (blocked K-fold, see :mod:`drafttwin.models.hybrid`), so ``e_d`` is an
honest out-of-sample residual; the GRU refitted on the whole training part is kept for
prediction.

Simulation mode (``task="simulation"``): the GRU is a NARX model run free from its own
outputs; each cross-fitting fold runs free over its held-out block from the block's first
``init_samples`` measured rows, which gives an honest out-of-sample free run ``yhat_d`` over
the training part. The residual model sees ``[yhat_m, dyhat_m, dyhat_d]`` (and the inputs),
never a measured residual (see :mod:`drafttwin.models.hybrid`). The free run's level is left
out: a black-box free run drifts far outside the range seen in training, its per-sample
change does not.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from drafttwin.errors import ConfigError, DataError
from drafttwin.models import simulation as sim
from drafttwin.models.datadriven import GRUModel
from drafttwin.models.hybrid import VARIANTS, _ResidualHybrid
from drafttwin.models.training import FitProgress
from drafttwin.models.windows import blocked_folds, first_target


class MDSL(_ResidualHybrid):
    """Multi-model residual learning hybrid.

    Args:
        variant: ``"md-s-l"`` (SKNet + LSTM), ``"md-l"`` (no SKNet) or ``"md-s"`` (no LSTM).
        use_disagreement: add ``yhat_d(T) - yhat_m(T)`` as an input (reported as ``+d``).
        window: residual window in samples. hidden / layers: LSTM residual-model size.
        sk_channels: SKNet width (multiple of 3; the 8 residual channels are lifted to it).
        data_window / data_hidden / data_layers: the GRU data-driven model.
        folds: contiguous blocks for cross-fitting the GRU over the training part.
        task / outputs / inputs / init_samples: see :mod:`drafttwin.models.simulation`.
        Other arguments: as :class:`drafttwin.models.GRUModel` (shared by both networks).
    """

    def __init__(
        self,
        variant: str = "md-s-l",
        use_disagreement: bool = False,
        window: int = 20,
        hidden: int = 48,
        layers: int = 2,
        sk_channels: int = 24,
        data_window: int = 20,
        data_hidden: int = 48,
        data_layers: int = 2,
        folds: int = 3,
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
        self.variant = variant
        self.use_disagreement = use_disagreement
        self.window = window
        self.hidden = hidden
        self.layers = layers
        self.sk_channels = sk_channels
        self.data_window = data_window
        self.data_hidden = data_hidden
        self.data_layers = data_layers
        self.folds = folds
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
        return self.variant + ("+d" if self.use_disagreement else "")

    @property
    def use_sknet(self) -> bool:  # type: ignore[override]
        return self.variant in ("md-s-l", "md-s")

    @property
    def use_lstm(self) -> bool:  # type: ignore[override]
        return self.variant in ("md-s-l", "md-l")

    def _check_params(self) -> None:
        super()._check_params()
        if self.variant not in VARIANTS:
            raise ConfigError(
                f"unknown MDSL variant {self.variant!r}", fix=f"use one of {', '.join(VARIANTS)}"
            )

    # --- residual channels --------------------------------------------------------
    def _groups(
        self, y: np.ndarray, mech: np.ndarray, data: np.ndarray | None
    ) -> dict[str, np.ndarray]:
        assert data is not None
        groups = {"em": y - mech, "ed": y - data}
        if self.use_disagreement:
            groups["dis"] = data - mech
        return groups

    def _channel_groups(self) -> tuple[str, ...]:
        return ("em", "ed")

    def _sim_channel_groups(self) -> tuple[str, ...]:
        # the free run's per-sample change only: its level drifts (hundreds of mm on EMPS)
        # beyond anything the residual model saw in training
        return ("ym", "dym", "dyd")

    def _extra_group(self) -> str | None:
        return "dis" if self.use_disagreement else None

    # --- the data-driven model ----------------------------------------------------
    def _data_model(self, seed: int) -> GRUModel:
        return GRUModel(
            window=self.data_window,
            hidden=self.data_hidden,
            layers=self.data_layers,
            dropout=self.dropout,
            lr=self.lr,
            batch_size=self.batch_size,
            epochs=self.epochs,
            patience=self.patience,
            val_fraction=self.val_fraction,
            clip_norm=self.clip_norm,
            skip=self.skip,
            horizon=self.horizon,
            seed=seed,
            device=self.device,
            quiet=True,
            task=self.task,
            outputs=self.outputs,
            inputs=self.inputs,
            init_samples=sim.init_rows(self) if sim.is_simulation(self) else self.init_samples,
            stride=self.stride,
        )

    def _fit_data(self, y: np.ndarray, u: np.ndarray, progress: FitProgress) -> np.ndarray:
        """Cross-fitted (out-of-sample) GRU predictions on the training part, (n, 4) rpm;
        also fits the GRU on the whole training part for prediction time."""
        if sim.is_simulation(self):
            return self._fit_data_sim(y, u, progress)
        start = first_target(self.data_window, self.horizon)
        if len(y) - start < 2 * self.folds:
            raise DataError(
                f"the training part ({len(y)} samples) is too short for {self.folds} "
                f"cross-fitting folds with a {self.data_window}-sample GRU window",
                fix="use a longer training part, fewer folds or a shorter data_window",
            )
        blocks = blocked_folds(start, len(y), self.folds)
        oof = np.full(y.shape, np.nan)
        for k, (a, b) in enumerate(blocks):
            fold = self._data_model(seed=self.seed + 1 + k)
            stage = f"GRU fold {k + 1}/{self.folds}"
            fold._fit_arrays(y, u=u, exclude=(a, b), progress=progress, stage=stage)
            oof[a:b] = fold._predict_arrays(y, u)[a:b]
        return self._finish_data(y, u, blocks, oof, progress)

    def _fit_data_sim(self, y: np.ndarray, u: np.ndarray, progress: FitProgress) -> np.ndarray:
        """Simulation mode: out-of-sample NARX free runs, one per held-out block, each from
        the block's own first ``init_samples`` measured rows."""
        init = sim.init_rows(self)
        if len(y) < self.folds * (init + self.data_window + 1):
            raise DataError(
                f"the training part ({len(y)} samples) is too short for {self.folds} "
                f"cross-fitting folds of free runs with {init} initialisation samples",
                fix="use a longer training part, fewer folds or fewer init_samples",
            )
        blocks = blocked_folds(0, len(y), self.folds)
        oof = np.full(y.shape, np.nan)
        for k, (a, b) in enumerate(blocks):
            fold = self._data_model(seed=self.seed + 1 + k)
            stage = f"GRU fold {k + 1}/{self.folds}"
            fold._fit_arrays(y, u=u, exclude=(a, b), progress=progress, stage=stage)
            oof[a:b] = fold._simulate_arrays(y, u, [(a, b)])[a:b]
        return self._finish_data(y, u, blocks, oof, progress)

    def _finish_data(self, y, u, blocks, oof: np.ndarray, progress: FitProgress) -> np.ndarray:
        full = self._data_model(seed=self.seed)
        full._fit_arrays(y, u=u, progress=progress, stage="GRU on the whole training part")
        self.data_model_ = full
        self.crossfit_blocks_ = blocks
        self.crossfit_pred_ = oof
        return oof

    def _predict_data(self, y: np.ndarray, u: np.ndarray) -> np.ndarray:
        if sim.is_simulation(self):  # the free run, its measured initialisation rows included
            return self.data_model_._simulate_arrays(y, u)
        return self.data_model_._predict_arrays(y, u)

    def predict_data_driven(self, series: Any) -> np.ndarray:
        """The internal GRU's predictions (fitted on the whole training part), (n, 4) rpm
        (simulation mode: its free run, NaN in the initialisation window)."""
        self._check_fitted()
        series = self._check_series(series)
        if sim.is_simulation(self):
            series = sim.blank_after_init(series, sim.init_rows(self))
        u = sim.input_matrix(series, sim.input_names(self))
        return self.data_model_._predict_arrays(series.values, u)

    # --- persistence ---------------------------------------------------------------
    def _get_state(self) -> tuple[dict[str, Any], dict[str, torch.Tensor]]:
        state, tensors = super()._get_state()
        data_state, data_tensors = self.data_model_._get_state()
        state["data_model"] = data_state
        state["crossfit_blocks"] = [list(b) for b in self.crossfit_blocks_]
        tensors.update({f"data.{k}": v for k, v in data_tensors.items()})
        tensors["crossfit_pred"] = torch.from_numpy(self.crossfit_pred_)
        return state, tensors

    def _set_state(self, state: dict[str, Any], tensors: dict[str, torch.Tensor]) -> None:
        super()._set_state(state, tensors)
        data = self._data_model(seed=self.seed)
        head = "data."
        data._set_state(
            state["data_model"],
            {k[len(head) :]: v for k, v in tensors.items() if k.startswith(head)},
        )
        data.rollers_ = self.rollers_
        self.data_model_ = data
        self.crossfit_blocks_ = [(int(a), int(b)) for a, b in state["crossfit_blocks"]]
        self.crossfit_pred_ = tensors["crossfit_pred"].numpy().astype(np.float64)
