"""The progress bars of a model fit (on stderr; silent with ``quiet``): one per training
stage, one per thread for stages that train side by side."""

from __future__ import annotations

import threading
from typing import Protocol

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
)


class Run(Protocol):
    """What a bar shows of a finished stage (a training ``History``)."""

    train_loss: list[float]
    best_epoch: int
    stopped_early: bool


class FitProgress:
    """The progress bars of one model fit: each training stage resets a bar (epochs as units).
    Stages that train side by side in threads (:mod:`.side_by_side`) get a bar each; a stage
    that finishes hands its bar to the next."""

    def __init__(self, description: str, *, quiet: bool = False) -> None:
        self.description = description
        self._progress = Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[loss]}"),
            TimeElapsedColumn(),
            console=Console(stderr=True),
            disable=quiet,
            transient=False,
        )
        self._bars = [self._progress.add_task(description, total=1, loss="", start=False)]
        self._held: dict[int, TaskID] = {}  # thread -> the bar its stage runs on
        self._lock = threading.Lock()

    def __enter__(self) -> FitProgress:
        self._progress.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._progress.stop()

    def _bar(self) -> TaskID:
        """This thread's bar: the one its stage holds, else the first free one (or a new)."""
        me = threading.get_ident()
        with self._lock:
            if me not in self._held:
                taken = set(self._held.values())
                free = [b for b in self._bars if b not in taken]
                if not free:
                    free = [self._progress.add_task(self.description, total=1, loss="",
                                                    start=False)]  # fmt: skip
                    self._bars.append(free[0])
                self._held[me] = free[0]
            return self._held[me]

    def stage(self, name: str, epochs: int) -> None:
        """Start a stage of ``epochs`` epochs on this thread's bar."""
        bar = self._bar()
        self._progress.reset(bar, total=epochs, description=f"{self.description}: {name}",
                             loss="")  # fmt: skip
        self._progress.start_task(bar)

    def epoch(self, train_loss: float, val_loss: float | None) -> None:
        text = f"loss {train_loss:.3g}" + ("" if val_loss is None else f" val {val_loss:.3g}")
        self._progress.update(self._bar(), advance=1, loss=text)

    def finish(self, history: Run | None = None) -> None:
        """End the stage: an early stop shows as such (the epochs run of the budget, and the
        best epoch), not as a full bar; a run cut to the epochs it turned out to need (a judge
        that trained ahead of its final net) shows those."""
        bar = self._bar()
        task = next(t for t in self._progress.tasks if t.id == bar)
        run = len(history.train_loss) if history is not None else 0
        if history is not None and history.stopped_early:
            self._progress.update(
                bar, total=run, completed=run,
                description=f"{task.description} (stopped early at epoch {run} of "
                f"{int(task.total or run)}: best {history.best_epoch + 1})",
            )  # fmt: skip
        elif history is not None and 0 < run < (task.total or 0):
            self._progress.update(bar, total=run, completed=run)
        else:
            self._progress.update(bar, completed=task.total)
        with self._lock:
            self._held.pop(threading.get_ident(), None)
