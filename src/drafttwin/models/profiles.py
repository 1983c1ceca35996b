"""Training profiles: named sets of hyperparameters (``quick``, ``standard``, ``paper``).

``paper`` is the paper's stated setting (GRU 3x128, LSTM residual model 3x256, dropout 0.2,
Adam lr 1e-3, batch 10, 500 epochs, no early stopping). What the paper leaves open is marked
as our assumption: the window length (20 samples), the SKNet width (48 channels), the
validation share (last 20 % of the training part), the number of cross-fitting folds (5).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any


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
        skip: networks predict a change on top of the last input step (see networks).
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

    def _training(self) -> dict[str, Any]:
        return {
            "dropout": self.dropout,
            "lr": self.lr,
            "batch_size": self.batch_size,
            "epochs": self.epochs,
            "patience": self.patience,
            "val_fraction": self.val_fraction,
            "clip_norm": self.clip_norm,
            "skip": self.skip,
        }

    def hyperparameters(self, model: str) -> dict[str, Any]:
        """Constructor keyword arguments for registry name ``model`` under this profile."""
        if model in ("mechanistic", "persistence"):
            return {}
        if model in ("gru", "lstm"):
            return {
                "window": self.window,
                "hidden": self.data_hidden,
                "layers": self.data_layers,
                **self._training(),
            }
        residual = {
            "window": self.window,
            "hidden": self.residual_hidden,
            "layers": self.residual_layers,
            **self._training(),
        }
        if model == "parallel":
            return residual
        return {
            **residual,
            "sk_channels": self.sk_channels,
            "data_window": self.window,
            "data_hidden": self.data_hidden,
            "data_layers": self.data_layers,
            "folds": self.folds,
        }

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


PROFILES: dict[str, Profile] = {
    "quick": Profile(
        name="quick",
        window=20,
        data_hidden=48,
        data_layers=2,
        residual_hidden=48,
        residual_layers=2,
        sk_channels=24,
        dropout=0.1,
        lr=2e-3,
        batch_size=64,
        epochs=30,
        patience=5,
        val_fraction=0.2,
        clip_norm=1.0,
        folds=3,
        skip=True,
    ),
    "standard": Profile(
        name="standard",
        window=30,
        data_hidden=128,
        data_layers=2,
        residual_hidden=128,
        residual_layers=2,
        sk_channels=48,
        dropout=0.2,
        lr=1e-3,
        batch_size=32,
        epochs=150,
        patience=15,
        val_fraction=0.2,
        clip_norm=1.0,
        folds=5,
        skip=True,
    ),
    "paper": Profile(
        name="paper",
        window=20,
        data_hidden=128,
        data_layers=3,
        residual_hidden=256,
        residual_layers=3,
        sk_channels=48,
        dropout=0.2,
        lr=1e-3,
        batch_size=10,
        epochs=500,
        patience=None,
        val_fraction=0.2,
        clip_norm=None,
        folds=5,
        skip=False,
    ),
}
