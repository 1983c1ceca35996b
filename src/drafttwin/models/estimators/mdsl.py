"""Multi-model residual learning (MD-S-L) and its ablations MD-L and MD-S (the paper's
multi-model residual hybrid).

Task ``prediction``, inputs for target row ``T`` (horizon ``h``, residual window ``W``):

* residual channels ``e_m = y - yhat_m`` and ``e_d = y - yhat_d`` at rows ``T-h-W+1 .. T-h``;
* optionally (``use_disagreement``) the current disagreement ``yhat_d(T) - yhat_m(T)``.

``yhat_d`` comes from the data-driven model (``data_model``, a GRU by default). While fitting,
``yhat_d`` over the training part is cross-fitted (blocked K-fold: fitted on the other
blocks, with every window touching the held-out block removed), so ``e_d`` is an honest
out-of-sample residual; the data-driven model refitted on the whole training part is kept for
prediction.

Task ``simulation``: the data-driven model is a NARX model run free from its own outputs; each
cross-fitting fold runs free over its held-out block (record by record) from its own first
``init_samples`` measured rows, an honest out-of-sample free run over the training part. The
residual model sees ``[yhat_m, dyhat_m, dyhat_d]`` (and the inputs), never a measured residual
(see :mod:`drafttwin.models.estimators.hybrid`). The free run's level is left out: a black-box free run
drifts far outside the range seen in training, its per-sample change does not.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Self

import numpy as np
import torch

from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import ConfigError, DataError
from drafttwin.models.estimators.datadriven import GRUModel, _RecurrentModel
from drafttwin.models.estimators.folds import DEFAULT_FOLDS
from drafttwin.models.estimators.hybrid import VARIANTS, Groups, _ResidualHybrid
from drafttwin.models.estimators.task import Task, blank_after_init, check_windows, input_matrix
from drafttwin.models.estimators.windows import blocked_folds, first_target
from drafttwin.models.training import FitProgress, Training


class MDSL(_ResidualHybrid):
    """Multi-model residual learning hybrid.

    Args:
        variant: ``"md-s-l"`` (SKNet + LSTM), ``"md-l"`` (no SKNet) or ``"md-s"`` (no LSTM).
        use_disagreement: add ``yhat_d(T) - yhat_m(T)`` as an input (reported as ``+d``).
        window: residual window, samples. hidden / layers: LSTM residual-model size.
        sk_channels: SKNet width (a multiple of 3; the residual channels are lifted to it).
        dropout / skip / accumulate / structure / fade / fallback / val_folds: as
            :class:`~drafttwin.models.ParallelHybrid`.
        folds: contiguous blocks for cross-fitting the data-driven model.
        data_model: the data-driven model's settings, as an unfitted
            :class:`~drafttwin.models.GRUModel` or :class:`~drafttwin.models.LSTMModel`
            (default ``GRUModel()``); its task is the MD model's, its seeds derive from the
            MD model's ``seed``.
        task / training / seed / quiet: as :class:`~drafttwin.models.GRUModel`; ``training``
            trains the residual model (the data-driven model keeps its own).
    """

    variant: str
    use_disagreement: bool
    sk_channels: int
    folds: int
    data_model: _RecurrentModel | None
    _shared_data: tuple[_RecurrentModel, np.ndarray, list[tuple[int, int]]] | None = None
    """A fitted data-driven model and its cross-fitted predictions (:meth:`use_data_model`)."""

    def __init__(
        self,
        variant: str = "md-s-l", use_disagreement: bool = False,
        window: int = 20, hidden: int = 48, layers: int = 2, sk_channels: int = 24,
        dropout: float = 0.1,
        skip: bool | None = None, accumulate: bool | None = None, structure: str = "absolute",
        fade: bool | str = False, fallback: bool = True, val_folds: int = DEFAULT_FOLDS,
        folds: int = 3, data_model: _RecurrentModel | None = None,
        task: Task = Task(), training: Training = Training(), seed: int = 0, quiet: bool = False,
    ) -> None:  # fmt: skip
        self._store_params(locals())

    @property
    def name(self) -> str:
        return self.variant + ("+d" if self.use_disagreement else "")

    @property
    def use_sknet(self) -> bool:
        return self.variant in ("md-s-l", "md-s")

    @property
    def use_lstm(self) -> bool:
        return self.variant in ("md-s-l", "md-l")

    def _check_params(self) -> None:
        super()._check_params()
        if self.variant not in VARIANTS:
            raise ConfigError(
                f"unknown MDSL variant {self.variant!r}", fix=f"use one of {', '.join(VARIANTS)}"
            )
        if self.data_model is not None and not isinstance(self.data_model, _RecurrentModel):
            raise ConfigError(
                f"data_model must be an unfitted GRUModel or LSTMModel, got "
                f"{type(self.data_model).__name__}",
                fix="pass data_model=GRUModel(window=..., hidden=..., layers=...)",
            )
        self._data_model(self.seed)._check_params()
        check_windows(self.task, data_window=self._template().window)

    # --- residual channels --------------------------------------------------------
    def _groups(self, y: np.ndarray, mech: np.ndarray, data: np.ndarray | None) -> Groups:
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
    def _window_lengths(self) -> list[int]:
        return [self.window, self._template().window]

    def _template(self) -> _RecurrentModel:
        return self.data_model if self.data_model is not None else GRUModel()

    def _data_model(self, seed: int) -> _RecurrentModel:
        """A fresh data-driven model with the MD model's task and the given seed."""
        template = self._template()
        task = self.task
        if task.simulation:
            task = task.replace(init_samples=self._init_rows())
        params = {**template.get_params(deep=False), "task": task, "seed": seed, "quiet": True}
        return type(template)(**params)

    # --- public: fit the data-driven model alone, or give a fitted one -----------------
    def fit_data_model(self, series: MeasurementSeries) -> np.ndarray:
        """Fit only the data-driven model on the training ``series`` (as :meth:`fit` would:
        cross-fitted folds and a refit on all of it) and return its cross-fitted predictions
        ``(n, channels)``. The fitted model is ``data_model_``, a complete estimator (it can
        be saved and loaded); pass it to :meth:`use_data_model` of other MD models trained on
        the same rows to share it."""
        self._check_params()
        series = self._check_series(series)
        u = input_matrix(series, self.task.inputs)
        self._shared_data = None
        with FitProgress("data model", quiet=bool(self.quiet)) as progress:
            oof = self._fit_data(series.values, u, series.record_starts, progress)
        dm = self.data_model_
        dm.channels_ = tuple(series.channels)
        dm.units_ = {n: series.unit(n) for n in (*series.channels, *self.task.inputs)}
        dm.mechanistic_spec_, dm.selection_, dm.provenance_ = None, {}, {}
        rate = series.sample_rate_hz
        dm.sample_rate_hz_ = float(rate) if np.isfinite(rate) else None
        return oof

    def use_data_model(
        self, model: _RecurrentModel, crossfit_pred: np.ndarray,
        blocks: Sequence[Sequence[int]],
    ) -> Self:  # fmt: skip
        """Use a fitted data-driven ``model`` and its cross-fitted predictions over the
        training rows (``crossfit_pred``, ``blocks``: what :meth:`fit_data_model` gave) in the
        next :meth:`fit` instead of fitting one (an ablation shares one data-driven model
        between its MD models). ``fit`` refuses predictions of another length."""
        if not isinstance(model, _RecurrentModel) or not hasattr(model, "net_"):
            raise ConfigError("use_data_model needs a fitted GRUModel or LSTMModel",
                              fix="fit it first (fit_data_model, or load a saved one)")  # fmt: skip
        pairs = [(int(a), int(b)) for a, b in blocks]
        self._shared_data = (model, np.asarray(crossfit_pred, dtype=np.float64), pairs)
        return self

    def _fit_data(
        self, y: np.ndarray, u: np.ndarray, starts: tuple[int, ...], progress: FitProgress
    ) -> np.ndarray:
        """Cross-fitted (out-of-sample) data-driven predictions on the training part; also
        fits the data-driven model on the whole training part for prediction time (unless
        :meth:`use_data_model` gave both)."""
        shared = self._shared_data
        if shared is not None:
            model, oof, blocks = shared
            if oof.shape != y.shape:
                raise DataError(
                    f"the shared data-driven predictions cover {oof.shape[0]} rows x "
                    f"{oof.shape[1] if oof.ndim == 2 else 1} channels, the training part "
                    f"{y.shape[0]} x {y.shape[1]}",
                    fix="fit the data-driven model on the same training rows",
                )
            self.data_model_, self.crossfit_blocks_, self.crossfit_pred_ = model, blocks, oof
            return oof
        data_window = self._template().window
        if self.task.simulation:
            init = self._init_rows()
            first, need = 0, self.folds * (init + data_window + 1)
        else:
            first = first_target(data_window, self.task.horizon)
            need = first + 2 * self.folds
        if len(y) < need:
            raise DataError(
                f"the training part ({len(y)} samples) is too short for {self.folds} "
                f"cross-fitting folds with a {data_window}-sample data-driven window",
                fix="use a longer training part, fewer folds or a shorter data-model window",
            )
        blocks = blocked_folds(first, len(y), self.folds)
        oof = np.full(y.shape, np.nan)
        for k, (a, b) in enumerate(blocks):
            fold = self._data_model(seed=self.seed + 1 + k)
            stage = f"data model fold {k + 1}/{self.folds}"
            fold._fit_arrays(y, u, starts, exclude=(a, b), progress=progress, stage=stage)
            if self.task.simulation:
                segments = _split_by_records(a, b, starts)
                oof[a:b] = fold._simulate_arrays(y, u, segments, self._init_rows())[a:b]
            else:
                oof[a:b] = fold._predict_arrays(y, u, starts)[a:b]
        full = self._data_model(seed=self.seed)
        full._fit_arrays(y, u, starts, progress=progress, stage="data model, whole training part")
        self.data_model_ = full
        self.crossfit_blocks_ = blocks
        self.crossfit_pred_ = oof
        return oof

    def _predict_data(self, y: np.ndarray, u: np.ndarray, starts: tuple[int, ...]) -> np.ndarray:
        if self.task.simulation:  # the free run, its measured initialisation rows included
            bounds = _split_by_records(0, len(y), starts)
            return self.data_model_._simulate_arrays(y, u, bounds, self._init_rows())
        return self.data_model_._predict_arrays(y, u, starts)

    def predict_data_driven(self, series: Any) -> np.ndarray:
        """The internal data-driven model's predictions (fitted on the whole training part),
        ``(n, channels)`` (simulation: its free run, NaN in the initialisation window)."""
        self._check_fitted()
        series = self._check_series(series)
        init = self._init_rows()
        if self.task.simulation:
            series = blank_after_init(series, init)
        u = input_matrix(series, self.task.inputs)
        return self.data_model_._predict_arrays(series.values, u, series.record_starts, init)

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
        data.channels_ = self.channels_
        data.units_ = self.units_
        head = "data."
        data._set_state(
            state["data_model"],
            {k[len(head) :]: v for k, v in tensors.items() if k.startswith(head)},
        )
        self.data_model_ = data
        self.crossfit_blocks_ = [(int(a), int(b)) for a, b in state["crossfit_blocks"]]
        self.crossfit_pred_ = tensors["crossfit_pred"].numpy().astype(np.float64)


def _split_by_records(a: int, b: int, starts: tuple[int, ...]) -> list[tuple[int, int]]:
    """Rows ``[a, b)`` cut at record boundaries (each piece runs free on its own)."""
    cuts = sorted({a, b, *(s for s in starts if a < s < b)})
    return list(zip(cuts[:-1], cuts[1:], strict=True))
