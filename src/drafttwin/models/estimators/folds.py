"""Validation that holds: a hybrid's residual model judged on blocked folds of its training
records, beside "no correction" (the physics alone).

One validation tail can mislead: a residual gain there need not carry to the next record (a
two-tank record's tail kept a residual model that doubled the test error). So every hybrid
also fits a *judge* per fold. With two or more training records the folds are whole records
(one each, or contiguous runs of them when there are more than :data:`DEFAULT_FOLDS`): a
held-out record brings its own offsets and load, as a test record does, where a block of one
record shares them with the rows its judge trained on (two records whose load offsets follow
their input ranges: blocks keep a correction that loses on a record with a new offset,
records do not). With one record its rows are cut into :data:`DEFAULT_FOLDS` contiguous
blocks. For block ``k`` a residual net with the final net's settings (its number of epochs,
as many as the final net needed) is trained on the windows that do not touch block ``k``, then
predicts block ``k`` (one step ahead; in a simulation a free run over the block, accumulated
from the measured residual just before it, as a test record runs from its initialisation
window). Each block scores every candidate (the residual level, accumulated changes, no
correction) by the NRMSE of the output on that block: RMSE over the standard deviation of the
measured residual ``y - physics`` there (so the physics alone scores 1, or more where the
residual has a mean).
Accumulated changes are also scored with no change predicted (the measured residual they
start from, held: ``held``).

The residual model is kept on an output channel only when it wins reliably there: that
channel's NRMSE lower than its baseline on every fold and, on its mean over the folds, by more
than :data:`~drafttwin.models.estimators.accumulation.CORRECTION_MARGIN` (the other channels
predict their physics). The baseline is the
physics alone, and for accumulated changes the lower of that and the held residual: a gain
that the held anchor scores as well is the measured start's, not the net's (on a record whose
regime changes, accumulation won every fold over the physics that way and lost on the test).
Where it keeps none, the hybrid predicts its physics exactly. A judge trains on every window outside its
block, for at most :data:`JUDGE_WINDOWS` windows' worth of steps per epoch of the final net
(:func:`judge_epochs`: on a longer record fewer passes over all of them), which keeps the
judges' cost a fraction of the final net's on dense data. The judges share the final net's
scalers (fitted on all training rows, so a held-out block's range is known to them: a min-max
scale, not its values)."""

from __future__ import annotations

import concurrent.futures as cf
import copy
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any, Protocol

import numpy as np
from torch import nn

from drafttwin.models.estimators import accumulation as acc
from drafttwin.models.estimators.windows import (
    blocked_folds,
    causal_ffill,
    footprint_outside,
    record_folds,
)
from drafttwin.models.training import (
    FitProgress,
    History,
    Training,
    debias_head,
    predict_network,
    runs_ahead,
    train_ahead,
    train_network,
)


class JudgedHybrid(Protocol):
    """What the folds ask of the residual hybrid they judge (``hybrid.JudgedHybrid``): its
    task, window, training settings, seed and name, its fitted scalers, its network and device
    (a protocol, so the judge does not import the hybrid that calls it)."""

    @property
    def task(self) -> Any: ...
    @property
    def window(self) -> int: ...
    @property
    def training(self) -> Any: ...
    @property
    def seed(self) -> int: ...
    @property
    def name(self) -> str: ...
    @property
    def scalers_(self) -> Any: ...
    def _build(self, n_out: int) -> nn.Module: ...
    def _device(self) -> str: ...
    def _init_rows(self) -> int: ...


DEFAULT_FOLDS = 3
"""Folds (records, or blocks of one record) of the training rows that judge a hybrid's
correction."""
JUDGE_WINDOWS = 2400
"""A judge trains at most this many windows' worth of steps per epoch of the final net: on
more windows it goes through all of them in fewer epochs (:func:`judge_epochs`). An
undertrained judge is a pessimistic one: at 600 (before 2026-11-29) the judges of a 300-s
plant record (7500 windows at stride 4) trained 9 % of the final net's steps, lost a fold and
threw away corrections that uncapped judges kept on every fold (MD-S-L one step ahead: test
RMSE front 1.04 -> 0.54 rpm, the GRU's 0.58); 1200 still refused MD-S-L's, 2400 gives the
uncapped judges' verdict on both hybrids (docs/models.md, "Validation on folds"). On the
default data it costs about 4 s of a 20-s fit."""
AHEAD_BYTES = 64 * 2**20
"""A judge trains ahead of its length at a constant rate only where its weights, kept once per
epoch to be cut back to, take at most this much memory (else it waits for its final net)."""
MEASURE = (
    "NRMSE of the output on each held-out fold of the training rows: RMSE / standard "
    "deviation of the measured residual (y - physics) there"
)
"""What the fold scores measure, as reports print it."""


@dataclass(frozen=True)
class FoldScores:
    """Per candidate (``none``, ``held``, ``offset``, ``level``, ``accumulate``,
    ``residual``), its NRMSE
    on each block (the mean over the output channels), the blocks' rows, and per candidate,
    block and channel the channel's NRMSE (``channel_scores``; ``None``: one channel, the
    mean's)."""

    scores: dict[str, list[float]]
    blocks: list[tuple[int, int]]
    rows: list[int]
    by_record: bool = False
    channel_scores: dict[str, list[list[float]]] | None = None

    def mean(self, candidate: str) -> float:
        values = [v for v in self.scores[candidate] if np.isfinite(v)]
        return float(np.mean(values)) if values else math.inf

    def baseline(self, candidate: str) -> list[float]:
        """Per fold, what ``candidate`` must beat: the physics alone, and for accumulated
        changes also the measured residual they start from, held (what they score with a net
        that predicts no change): the lower of the two."""
        return [float(v) for v in self._against(candidate, self._means)[1]]

    def wins(self, candidate: str) -> int:
        """Folds on which ``candidate`` scores below its :meth:`baseline`."""
        return _wins(*self._against(candidate, self._means))

    def reliable(self, candidate: str) -> bool:
        """Below its :meth:`baseline` on every fold, and on the mean over the folds by more
        than :data:`~drafttwin.models.estimators.accumulation.CORRECTION_MARGIN`."""
        return _wins_reliably(*self._against(candidate, self._means))

    def channel_wins(self, candidate: str) -> list[int]:
        """Per output channel, the folds on which ``candidate`` scores below its baseline."""
        c, b = self._against(candidate, self._per_channel)
        return [_wins(c[:, j], b[:, j]) for j in range(c.shape[1])]

    def channel_reliable(self, candidate: str) -> list[bool]:
        """Per output channel, :meth:`reliable`'s rule on that channel's NRMSE alone."""
        c, b = self._against(candidate, self._per_channel)
        return [_wins_reliably(c[:, j], b[:, j]) for j in range(c.shape[1])]

    def _means(self, candidate: str) -> np.ndarray:
        """(folds,) NRMSE of ``candidate``, the mean over the channels."""
        return np.asarray(self.scores[candidate], dtype=float)

    def _per_channel(self, candidate: str) -> np.ndarray:
        """(folds, channels) NRMSE of ``candidate``."""
        if self.channel_scores is None:
            return self._means(candidate)[:, None]
        return np.asarray(self.channel_scores[candidate], dtype=float)

    def _against(
        self, candidate: str, table: Callable[[str], np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray]:
        """``candidate``'s scores and its baseline's (see :meth:`baseline`) from ``table``
        (the means over the channels, or per channel)."""
        none = table(acc.CORRECTION_NONE)
        if candidate == "accumulate" and acc.CORRECTION_HELD in self.scores:
            none = np.fmin(none, table(acc.CORRECTION_HELD))
        return table(candidate), none

    def chosen(
        self, candidate: str, corrected: Sequence[bool], offset: Sequence[bool] = ()
    ) -> list[float]:
        """Per fold, the mean NRMSE over the channels of the prediction as chosen: the
        measured offset held on the ``offset`` channels, ``candidate`` on the other
        ``corrected`` channels, the physics alone on the rest."""
        mask = np.asarray(corrected, dtype=bool)
        c, none = self._per_channel(candidate), self._per_channel(acc.CORRECTION_NONE)
        table = np.where(mask[None, :], c, none)
        if any(offset):
            held = np.asarray(offset, dtype=bool)
            table = np.where(held[None, :], self._per_channel(acc.CORRECTION_OFFSET), table)
        return [float(v) for v in table.mean(axis=1)]

    def channel_means(self, candidate: str) -> np.ndarray:
        """Per output channel, ``candidate``'s mean NRMSE over its finite folds."""
        table = self._per_channel(candidate)
        finite = np.isfinite(table)
        count = finite.sum(axis=0)
        total = np.where(finite, table, 0.0).sum(axis=0)
        return np.where(count > 0, total / np.maximum(count, 1), np.inf)

    def to_dict(self) -> dict[str, object]:
        clean = {k: [v if np.isfinite(v) else None for v in vals]
                 for k, vals in self.scores.items()}  # fmt: skip
        out: dict[str, object] = {
            "fold_nrmse": clean, "folds": len(self.blocks),
            "fold_blocks": [list(b) for b in self.blocks], "fold_rows": self.rows,
            "fold_by": "record" if self.by_record else "block"}  # fmt: skip
        if self.channel_scores is not None and len(self.channel_scores[acc.CORRECTION_NONE][0]) > 1:
            out["channel_fold_nrmse"] = {
                k: [[v if np.isfinite(v) else None for v in fold] for fold in per_fold]
                for k, per_fold in self.channel_scores.items()}  # fmt: skip
        return out


def _wins(scores: np.ndarray, baseline: np.ndarray) -> int:
    """Folds on which ``scores`` lie below ``baseline`` (one value per fold each)."""
    return int((np.isfinite(scores) & (scores < baseline)).sum())


def _wins_reliably(scores: np.ndarray, baseline: np.ndarray) -> bool:
    """Below ``baseline`` on every fold, and on the mean over the folds by more than
    :data:`~drafttwin.models.estimators.accumulation.CORRECTION_MARGIN` (the baseline's mean
    over its finite folds)."""
    base = baseline[np.isfinite(baseline)]
    mean_base = float(np.mean(base)) if base.size else math.inf
    return (_wins(scores, baseline) == scores.size
            and float(np.mean(scores)) < (1.0 - acc.CORRECTION_MARGIN) * mean_base)  # fmt: skip


def judge(
    model: JudgedHybrid,
    fits: Mapping[bool, tuple[nn.Module, History, np.ndarray]],
    judges: Mapping[tuple[int, bool], nn.Module],
    x: np.ndarray,
    extra: np.ndarray | None,
    scaled: dict[str, np.ndarray],
    rows: np.ndarray,
    em: np.ndarray,
    residual: np.ndarray,
    level: np.ndarray | float,
    starts: Sequence[int],
) -> FoldScores | None:
    """Fold scores of every candidate in ``fits`` (accumulate flag -> final net, its history,
    its usable-window mask) and of no correction, from ``judges`` ((fold, accumulate flag) ->
    the judge :func:`train_judge` trained); ``None`` with fewer than two folds.
    ``em``: the residual as the net sees it (relative structure: over the physics' level);
    ``residual``: ``y - physics`` in the output's units; ``level``: what turns one into the
    other."""
    k_folds = int(getattr(model, "val_folds", DEFAULT_FOLDS))
    if k_folds < 2 or rows.size == 0:
        return None
    blocks, by_record = _folds(rows, starts, k_folds)
    anchors = causal_ffill(em, starts)
    offered = offset_offered(model, by_record)
    channel: dict[str, list[list[float]]] = {acc.CORRECTION_NONE: []}
    n_rows = []
    for k, block in enumerate(blocks):
        held = (rows >= block[0]) & (rows < block[1])
        target_rows = rows[held]
        measured = residual[target_rows]
        scale = np.nanstd(measured, axis=0)
        scale = np.where(np.isfinite(scale) & (scale > 0), scale, 1.0)
        channel[acc.CORRECTION_NONE].append(
            acc.channel_nrmse(np.zeros_like(measured), measured, scale).tolist()
        )
        n_rows.append(int(held.sum()))
        lev = level[target_rows] if isinstance(level, np.ndarray) else level
        if offered:  # held in the output's units (relative structure too: see hybrid.py)
            offset = acc.offset_runs(target_rows, residual, starts, model._init_rows())
            channel.setdefault(acc.CORRECTION_OFFSET, []).append(
                acc.channel_nrmse(offset, measured, scale).tolist()
            )
        for accumulate in fits:
            name = _name(model, accumulate)
            net = judges[(k, accumulate)]
            ev = None if extra is None else extra[held]
            usable = np.isfinite(x[held]).reshape(int(held.sum()), -1).all(axis=1)
            pred = np.full(measured.shape, np.nan)
            if usable.any():
                out = predict_network(net, x[held][usable],
                                      extra=None if ev is None else ev[usable],
                                      device=model._device())  # fmt: skip
                key = "dem" if accumulate else "em"
                pred[usable] = model.scalers_[key].inverse_transform(out)
            if accumulate:
                pred = acc.accumulate_runs(pred, target_rows, anchors, starts)
                # the same runs with no change predicted: the anchor held, on the same rows
                hold = acc.accumulate_runs(np.where(np.isfinite(pred), 0.0, np.nan), target_rows,
                                           anchors, starts)  # fmt: skip
                channel.setdefault(acc.CORRECTION_HELD, []).append(
                    acc.channel_nrmse(hold * lev, measured, scale).tolist()
                )
            channel.setdefault(name, []).append(
                acc.channel_nrmse(pred * lev, measured, scale).tolist()
            )
    scores = {k: [float(np.mean(v)) for v in per_fold] for k, per_fold in channel.items()}
    return FoldScores(scores, blocks, n_rows, by_record, channel)


def offset_offered(model: JudgedHybrid, by_record: bool) -> bool:
    """Whether the measured offset held (:data:`~drafttwin.models.estimators.accumulation.
    CORRECTION_OFFSET`) is judged: in a simulation on folds of whole records, unless the user
    kept the net's correction untested (``fallback=False``)."""
    return bool(model.task.simulation and by_record and getattr(model, "fallback", True))


def fold_blocks(
    model: JudgedHybrid, rows: np.ndarray, starts: Sequence[int]
) -> list[tuple[int, int]] | None:
    """The held-out blocks :func:`judge` scores on (``None``: it judges nothing)."""
    k_folds = int(getattr(model, "val_folds", DEFAULT_FOLDS))
    if k_folds < 2 or rows.size == 0:
        return None
    return _folds(rows, starts, k_folds)[0]


def folds_are_records(model: JudgedHybrid, rows: np.ndarray, starts: Sequence[int]) -> bool | None:
    """Whether :func:`judge` will hold out whole training records (``True``) or blocks of
    one record (``False``); ``None`` when it judges nothing (fewer than two folds)."""
    k_folds = int(getattr(model, "val_folds", DEFAULT_FOLDS))
    if k_folds < 2 or rows.size == 0:
        return None
    return _folds(rows, starts, k_folds)[1]


def _folds(
    rows: np.ndarray, starts: Sequence[int], k_folds: int
) -> tuple[list[tuple[int, int]], bool]:
    """The held-out blocks and whether they are records: whole training records when two or
    more hold target rows (:func:`~drafttwin.models.estimators.windows.record_folds`),
    contiguous blocks of the rows otherwise."""
    start, stop = int(rows.min()), int(rows.max()) + 1
    if any(start < s < stop for s in starts):
        blocks = [b for b in record_folds(start, stop, starts, k_folds)
                  if ((rows >= b[0]) & (rows < b[1])).any()]  # fmt: skip
        if len(blocks) > 1:
            return blocks, True
    return blocked_folds(start, stop, k_folds), False


def _name(model: JudgedHybrid, accumulate: bool) -> str:
    if not model.task.simulation:
        return "residual"
    return "accumulate" if accumulate else "level"


def train_judge(
    model: JudgedHybrid, net: nn.Module, k: int, block: tuple[int, int], accumulate: bool,
    final: cf.Future[History], x: np.ndarray, extra: np.ndarray | None,
    scaled: dict[str, np.ndarray], rows: np.ndarray, ok: np.ndarray, lag: int,
    progress: FitProgress | None,
) -> Callable[[], nn.Module]:  # fmt: skip
    """Train ``net`` (built from the hybrid's seed) on the windows outside ``block`` with the
    final net's settings, for as many epochs as the final net needed (:func:`judge_epochs`:
    fewer over all of them on a long record). ``final``: that net's history once it has ended;
    until then the judge trains ahead (``train_ahead``: to be cut back to its length, or on a
    learning-rate schedule a bet on the whole budget, trained again from the same start if
    lost). Returns the step that ends the judge once ``final`` is known (its length, an
    accumulated-change head re-fitted) and gives the net."""
    keep = ok & footprint_outside(rows, model.window, lag, block)
    target = scaled["dem" if accumulate else "em"][rows]
    tr = model.training
    n = len(range(0, int(keep.sum()), tr.stride))  # the windows an epoch goes through
    settings = tr.replace(epochs=judge_epochs(tr.epochs, n), patience=None, val_fraction=0.0)
    until: cf.Future[int] = cf.Future()
    final.add_done_callback(partial(_judge_length, until, n))
    ek = None if extra is None else extra[keep]
    what = " (accumulated changes)" if accumulate else ""
    stage = f"{model.name} validation fold {k + 1}{what}"
    seed = model.seed + 101 + k
    if until.done() or _snapshot_bytes(net, settings) > AHEAD_BYTES:
        train_network(net, x[keep], target[keep], settings, seed=seed, extra=ek,
                      progress=progress, stage=stage, until=until)  # fmt: skip
        ahead = None
    else:
        start = copy.deepcopy(net.state_dict())  # to train again if the bet on its length lost
        ahead = (train_ahead(net, x[keep], target[keep], settings, until=until, seed=seed,
                             extra=ek, progress=progress, stage=stage), start)  # fmt: skip

    def end() -> nn.Module:
        if ahead is not None and not ahead[0].cut(net, until.result()):
            net.load_state_dict(ahead[1])
            train_network(net, x[keep], target[keep], settings, seed=seed, extra=ek,
                          progress=progress, stage=stage, until=until)  # fmt: skip
        if accumulate:
            s = tr.stride
            debias_head(net, x[keep][::s], target[keep][::s], None if ek is None else ek[::s],
                        model._device())  # fmt: skip
        return net

    return end


def _snapshot_bytes(net: nn.Module, settings: Training) -> int:
    """What a judge trained ahead may keep: its weights once per epoch (at a constant rate)."""
    if not runs_ahead(settings):
        return 0
    weights = sum(int(t.numel()) * int(t.element_size()) for t in net.state_dict().values())
    return settings.epochs * weights


def _judge_length(until: cf.Future[int], n_windows: int, final: cf.Future[History]) -> None:
    """Tell a judge its epochs once its final net has ended (or that it failed)."""
    error = final.exception()
    if error is not None:
        until.set_exception(error)
        return
    until.set_result(judge_epochs(final.result().best_epoch + 1, n_windows))


def judge_epochs(final_epochs: int, n_windows: int) -> int:
    """A judge's epochs: the final net's (``final_epochs``, as many as it needed), over at most
    :data:`JUDGE_WINDOWS` windows' worth of steps each; a judge with more windows than that
    goes through all of them fewer times (at least once), so its cost stops growing with the
    record's length."""
    final_epochs = max(1, final_epochs)
    if n_windows <= JUDGE_WINDOWS:
        return final_epochs
    return max(1, round(final_epochs * JUDGE_WINDOWS / n_windows))
