"""Training profiles: named sets of hyperparameters (``quick``, ``standard``, ``paper``).

``paper`` is the paper's stated setting (GRU 3x128, LSTM residual model 3x256, dropout 0.2,
Adam lr 1e-3, batch 10, 500 epochs, no early stopping). What the paper leaves open is marked
as our assumption: the window length (20 samples), the SKNet width (48 channels), the
validation share (last 20 % of the training part), the number of cross-fitting folds (5).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from drafttwin.models.estimators.datadriven import GRUModel
from drafttwin.models.estimators.task import Task
from drafttwin.models.training import Training


@dataclass(frozen=True)
class Profile:
    """Hyperparameters shared by all models of one study.

    Attributes:
        name: profile name.
        window: input window length in samples (data-driven and residual models).
        data_hidden / data_layers: GRU/LSTM data-driven model size.
        residual_hidden / residual_layers: LSTM residual-model size (parallel, MD-*).
        sk_channels: SKNet width (a multiple of 3).
        dropout: dropout probability.
        lr: Adam learning rate.
        batch_size: samples per optimiser step.
        epochs: maximum number of epochs.
        patience: epochs without validation improvement before stopping; ``None`` = never stop.
        val_fraction: share of the training samples, taken from the end, used for validation.
        clip_norm: gradient-norm clipping threshold; ``None`` = no clipping.
        folds: blocks for cross-fitting the data-driven model inside MD-S-L.
        skip: one-step prediction: networks predict a change on top of the last input step
            (an architecture prior: an untrained net is persistence); the paper's networks
            do not. Not used in a simulation, where residual accumulation is chosen on
            validation data instead.
    """

    name: str
    window: int
    data_hidden: int
    data_layers: int
    residual_hidden: int
    residual_layers: int
    sk_channels: int
    dropout: float
    lr: float
    batch_size: int
    epochs: int
    patience: int | None
    val_fraction: float
    clip_norm: float | None
    folds: int
    skip: bool
    schedule: str

    def training(self) -> Training:
        """The training settings of every network under this profile."""
        return Training(epochs=self.epochs, batch_size=self.batch_size, lr=self.lr,
                        patience=self.patience, val_fraction=self.val_fraction,
                        clip_norm=self.clip_norm, schedule=self.schedule)  # fmt: skip

    def hyperparameters(self, model: str, task: Task | None = None) -> dict[str, Any]:
        """Constructor keyword arguments for registry name ``model`` under this profile and
        ``task`` (``skip`` applies to one-step prediction only, so a simulation leaves it
        unset)."""
        if model in ("mechanistic", "persistence"):
            return {}
        common: dict[str, Any] = {"window": self.window, "dropout": self.dropout,
                                  "training": self.training()}  # fmt: skip
        if task is None or not task.simulation:
            common["skip"] = self.skip
        if model in ("gru", "lstm"):
            return {**common, "hidden": self.data_hidden, "layers": self.data_layers}
        residual = {**common, "hidden": self.residual_hidden, "layers": self.residual_layers}
        if model == "parallel":
            return residual
        data = {**common, "window": self.window, "hidden": self.data_hidden,
                "layers": self.data_layers}  # fmt: skip
        return {**residual, "sk_channels": self.sk_channels, "folds": self.folds,
                "data_model": GRUModel(**data)}  # fmt: skip

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


# One row per profile, in the field order of Profile: name, window, data-driven model hidden and
# layers, residual model hidden and layers, sk_channels, dropout, lr, batch_size, epochs,
# patience, val_fraction, clip_norm, folds, skip, schedule (so the profiles compare column by
# column). The quick profile's 20 epochs on a cosine schedule: on the default data (parallel,
# seeds 0-2) a lower validation loss than 30 constant-rate epochs with early stopping, in about
# 0.7x its time on the seed that ran all 30 (docs/models.md, "Training").
# Its residual LSTM has one layer of 48 (two before 2026-12-01): on the default data (seeds
# 0-2) the parallel hybrid's mean fold NRMSE 0.703 against 0.704 and MD-S-L's 0.644 against
# 0.648 (seeds 0-1), in half the residual net's time; the test RMSE within 1.2 % (docs/models.md,
# "Training").
# fmt: off
_ROWS = (
    #       name        win data    resid.  sk  drop lr    batch epoch pat.  val  clip  fold skip   sched.
    Profile("quick",    20, 48, 2,  48, 1,  24, 0.1, 2e-3, 64,   20,   5,    0.2, 1.0,  3,   True,  "cosine"),
    Profile("standard", 30, 128, 2, 128, 2, 48, 0.2, 1e-3, 32,   150,  15,   0.2, 1.0,  5,   True,  "constant"),
    Profile("paper",    20, 128, 3, 256, 3, 48, 0.2, 1e-3, 10,   500,  None, 0.2, None, 5,   False, "constant"),
)
# fmt: on
PROFILES: dict[str, Profile] = {p.name: p for p in _ROWS}
DEFAULT_PROFILE = "quick"
"""The profile of a model built without one (``make_model``, ``fit``)."""
