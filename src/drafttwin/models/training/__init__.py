"""Training: the one loop every network trains through (:mod:`.loop`: Adam, batches,
validation, early stopping, a run trained ahead of its length), its progress bars
(:mod:`.progress`), where and how it computes (:mod:`.compute`: device, threads,
determinism), its own random numbers (:mod:`.rng`), nets trained side by side in threads
(:mod:`.side_by_side`) and Adam on the CPU (:mod:`.adam`)."""

from drafttwin.models.training.loop import (
    Ahead,
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
from drafttwin.models.training.progress import FitProgress

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
