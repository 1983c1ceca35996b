"""The parallel hybrid (paper section 3.2): the physics' prediction plus a residual LSTM's
(:mod:`drafttwin.models.estimators.hybrid` holds the residual machinery it shares with
MD-S-L)."""

from __future__ import annotations

from drafttwin.models.estimators.folds import DEFAULT_FOLDS
from drafttwin.models.estimators.hybrid import _ResidualHybrid
from drafttwin.models.estimators.task import Task
from drafttwin.models.training import Training


class ParallelHybrid(_ResidualHybrid):
    """Parallel hybrid: an LSTM learns the mechanistic residual; output ``yhat_m + ehat_m``.

    Args:
        window: residual window, samples. hidden / layers: LSTM size. dropout: between layers.
        skip: prediction: the head predicts a change on top of the last residual (``None``:
            True); must stay ``None`` in a simulation.
        accumulate: simulation: predict the residual's per-sample change and sum it (True) or
            its level (False); ``None`` (default): both are trained and the one with the
            smaller free-run error on the validation part of the training data is kept
            (``selection_`` says which, with the scores). Must stay ``None`` in prediction.
        structure: ``"absolute"`` (speeds as they are) or ``"relative"`` (residual and speeds
            as fractions of the physics' speed, inputs over their training mean); see the
            module docstring.
        fade: scale the correction down outside the training range (back to the physics);
            ``"strict"``: also off wherever a channel held constant in training (a set-point)
            leaves its training value.
        fallback: keep the residual model only when it beats the physics alone on validation
            data (``False``: keep it untested; the scores are still recorded).
        val_folds: blocked folds of the training rows that judge the residual model against
            the physics alone and choose accumulation (:mod:`drafttwin.models.estimators.folds`); 1: the
            validation tail of the training alone (as model files before it).
        task / training / seed / quiet: as :class:`~drafttwin.models.GRUModel`.
    """

    def __init__(
        self,
        window: int = 20, hidden: int = 48, layers: int = 2, dropout: float = 0.1,
        skip: bool | None = None, accumulate: bool | None = None, structure: str = "absolute",
        fade: bool | str = False, fallback: bool = True, val_folds: int = DEFAULT_FOLDS,
        task: Task = Task(), training: Training = Training(), seed: int = 0, quiet: bool = False,
    ) -> None:  # fmt: skip
        self._store_params(locals())

    @property
    def name(self) -> str:
        return "parallel"
