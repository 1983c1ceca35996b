"""The nets a hybrid's fit trains, and in what order: each candidate's final net, then a judge
per fold and candidate (:mod:`~drafttwin.models.estimators.folds`), side by side where they
can (:mod:`~drafttwin.models.training.side_by_side`).

A judge trains for as many epochs as its candidate's final net needed
(:func:`~drafttwin.models.estimators.folds.judge_epochs`), so it cannot know its length before
that net ends; it trains ahead beside it: at a constant learning rate it is cut back to that
length once known (the same numbers: a shorter run is the start of a longer one), on a
schedule over the epochs it bets on the whole budget and trains again when the final net ended
early enough to change its length (``train_ahead``). So the one
candidate of a one-step prediction trains beside its judges, and a simulation's two candidates
beside each other. Every net is built here, in the calling thread, from its seed; each
trains with its own generators, so the numbers are those of the nets trained one after the
other, whatever the number of threads.
"""

from __future__ import annotations

import concurrent.futures as cf
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any, Protocol

import numpy as np
import torch
from torch import nn

from drafttwin.models.estimators.folds import JudgedHybrid, fold_blocks, train_judge
from drafttwin.models.training import FitProgress, History
from drafttwin.models.training.compute import compute_context, resolve_device
from drafttwin.models.training.rng import draws_global_rng
from drafttwin.models.training.side_by_side import side_by_side, training_workers

FinalFit = tuple[Any, History, np.ndarray]
"""A candidate's final net, its history and its usable-window mask."""


class ScheduledHybrid(JudgedHybrid, Protocol):
    """What the schedule asks of the hybrid besides what its judges ask: its final nets'
    training (``_train_final``: the net built here, its targets and mask)."""

    def _train_final(
        self, net: nn.Module, x: np.ndarray, target: np.ndarray, extra: np.ndarray | None,
        ok: np.ndarray, progress: FitProgress, accumulate: bool,
    ) -> History: ...  # fmt: skip


@dataclass(frozen=True)
class Windows:
    """The scaled windows a hybrid trains on: ``x`` (N, T, F), ``extra`` (N, E) or ``None``,
    the scaled channel groups and the target rows."""

    x: np.ndarray
    extra: np.ndarray | None
    scaled: dict[str, np.ndarray]
    rows: np.ndarray


def train_residual_nets(
    model: ScheduledHybrid, windows: Windows, starts: tuple[int, ...], candidates: list[bool],
    usable: Callable[[np.ndarray], np.ndarray], progress: FitProgress,
) -> tuple[dict[bool, FinalFit], dict[tuple[int, bool], nn.Module]]:  # fmt: skip
    """Per candidate (accumulate flag) its final net, history and usable windows, and per
    (fold, candidate) its judge (none with fewer than two folds). ``usable(target)``: the
    windows whose values are all finite."""
    lag = 0 if model.task.simulation else model.task.horizon
    blocks = fold_blocks(model, windows.rows, starts) or []
    jobs: list[Callable[[], Any]] = []
    nets: list[nn.Module] = []
    ended: dict[bool, cf.Future[History]] = {}
    masks: dict[bool, np.ndarray] = {}
    for accumulate in candidates:
        target = windows.scaled["dem" if accumulate else "em"][windows.rows]
        masks[accumulate] = ok = usable(target)
        ended[accumulate] = cf.Future()
        nets.append(model._build(target.shape[1]))
        jobs.append(partial(_final, model, nets[-1], windows, target, ok, progress, accumulate,
                            ended[accumulate]))  # fmt: skip
    keys = [(k, a) for k in range(len(blocks)) for a in candidates]
    for k, accumulate in keys:
        nets.append(model._build(windows.scaled["dem" if accumulate else "em"].shape[1]))
        jobs.append(partial(train_judge, model, nets[-1], k, blocks[k], accumulate,
                            ended[accumulate], windows.x, windows.extra, windows.scaled,
                            windows.rows, masks[accumulate], lag, progress))  # fmt: skip
    device = resolve_device(model.training.device)
    alone = device.type != "cpu" or any(map(draws_global_rng, nets))
    workers = 1 if alone else training_workers()
    with compute_context(device), torch.random.fork_rng(devices=[]):
        results = side_by_side(jobs, workers)
        ends = side_by_side(results[len(candidates) :], workers)  # judges cut to their length
    finals = {a: (nets[i], results[i], masks[a]) for i, a in enumerate(candidates)}
    return finals, dict(zip(keys, ends, strict=True))


def _final(
    model: ScheduledHybrid, net: nn.Module, windows: Windows, target: np.ndarray,
    ok: np.ndarray, progress: FitProgress, accumulate: bool, ended: cf.Future[History],
) -> History:  # fmt: skip
    """Train a candidate's final net; its end (or failure) tells its judges their length."""
    try:
        history = model._train_final(net, windows.x, target, windows.extra, ok, progress,
                                     accumulate)  # fmt: skip
    except BaseException as exc:
        ended.set_exception(exc)
        raise
    ended.set_result(history)
    return history
