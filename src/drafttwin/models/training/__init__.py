"""Training: the one loop every network trains through (:mod:`.loop`: Adam, batches,
validation, early stopping, the progress bar), where and how it computes (:mod:`.compute`:
device, threads, determinism) and Adam on the CPU (:mod:`.adam`)."""

from drafttwin.models.training.loop import (
    Ahead,
    FitProgress,
    History,
    HistoryDict,
    Training,
    debias_head,
    predict_network,
    runs_ahead,
    split_sizes,
    train_ahead,
    train_network,
)

__all__ = [
    "Ahead",
    "FitProgress",
    "History",
    "HistoryDict",
    "Training",
    "debias_head",
    "predict_network",
    "runs_ahead",
    "split_sizes",
    "train_ahead",
    "train_network",
]
