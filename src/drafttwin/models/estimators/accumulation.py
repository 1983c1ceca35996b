"""Residual accumulation in a simulation, and choosing it on validation data.

In a free run no measured residual exists after the initialisation window, so a residual
model predicts either the mechanistic residual ``e_m(T)`` itself (its *level*) or its
per-sample change, summed from the last measured residual (*accumulation*). Which is better
depends on the data: accumulation suits a physics error that drifts (EMPS: friction and
offset errors integrate twice open loop), the level suits a bounded error. So the hybrids
train both and keep the one with the smaller free-run error over the validation part of the
training data (:func:`choose`), unless the user fixed it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from torch import nn

from drafttwin.models.estimators.windows import record_ids
from drafttwin.models.training import predict_network, split_sizes


class FoldScoresLike(Protocol):
    """What :func:`choose_on_folds` reads of :class:`drafttwin.models.estimators.folds.FoldScores`."""

    @property
    def scores(self) -> dict[str, list[float]]: ...

    @property
    def rows(self) -> list[int]: ...

    def mean(self, candidate: str) -> float: ...

    def wins(self, candidate: str) -> int: ...

    def reliable(self, candidate: str) -> bool: ...

    def channel_reliable(self, candidate: str) -> list[bool]: ...

    def channel_wins(self, candidate: str) -> list[int]: ...

    def chosen(
        self, candidate: str, corrected: Sequence[bool], offset: Sequence[bool] = ()
    ) -> list[float]: ...

    def channel_means(self, candidate: str) -> np.ndarray: ...


def validation_slice(n_samples: int, val_fraction: float, stride: int) -> slice:
    """The samples (in chronological order, before ``stride`` subsampling) that
    :func:`~drafttwin.models.training.train_network` holds out for validation: the time span
    after its last strided training sample, at full resolution. Empty without a validation
    part."""
    n_strided = len(range(0, n_samples, max(1, stride)))
    n_train, n_val = split_sizes(n_strided, val_fraction)
    if n_val == 0:
        return slice(n_samples, n_samples)
    return slice(n_train * max(1, stride), n_samples)


def drift_validator(
    x: np.ndarray,
    target: np.ndarray,
    extra: np.ndarray | None,
    val_fraction: float,
    stride: int,
) -> Callable[[nn.Module], float] | None:
    """Early-stopping criterion of an accumulating residual model: the mean squared drift of
    the accumulated predicted changes over the validation part, in scaled units squared.
    ``None`` when there is no validation part."""
    val = validation_slice(len(x), val_fraction, stride)
    if val.start >= len(x):
        return None
    xv, tv = x[val], target[val]
    ev = None if extra is None else extra[val]

    def score(net: nn.Module) -> float:
        device = str(next(net.parameters()).device)
        out = predict_network(net, xv, extra=ev, device=device)
        drift = np.cumsum(out - tv, axis=0)
        return float(np.mean(drift**2))

    return score


def record_runs(
    rows: np.ndarray, n_rows: int, starts: Sequence[int]
) -> Iterator[tuple[np.ndarray, int, int]]:
    """The runs of consecutive target ``rows`` within one record of an ``n_rows``-row
    series: per run, its positions in ``rows``, its first row and its record's first row."""
    if rows.size == 0:
        return
    n = int(max(rows.max() + 1, n_rows))
    rec = record_ids(n, starts)
    firsts = [0, *sorted(int(s) for s in starts if 0 < s < n)]  # record k's first row
    breaks = np.flatnonzero((np.diff(rows) != 1) | (rec[rows[1:]] != rec[rows[:-1]])) + 1
    for seg in np.split(np.arange(rows.size), breaks):
        first = int(rows[seg[0]])
        yield seg, first, firsts[rec[first]]


def accumulate_runs(
    steps: np.ndarray, rows: np.ndarray, anchors: np.ndarray, starts: Sequence[int]
) -> np.ndarray:
    """Levels rebuilt from per-sample changes ``steps`` at target ``rows``: each run of
    consecutive rows of one record starts from ``anchors[row - 1]`` (the level just before
    it) and adds the changes up. Same shape as ``steps``."""
    out = np.empty_like(steps)
    for seg, first, _ in record_runs(rows, anchors.shape[0], starts):
        out[seg] = anchors[first - 1] + np.cumsum(steps[seg], axis=0)
    return out


def offset_runs(
    rows: np.ndarray, measured: np.ndarray, starts: Sequence[int], n_init: int
) -> np.ndarray:
    """The measured offset held (:data:`CORRECTION_OFFSET`) at target ``rows``: each run of
    consecutive rows of one record takes the mean of ``measured`` over up to ``n_init`` rows
    just before it in its record (finite values only; 0, the physics alone, where none is),
    held over the run. Shape ``(len(rows), channels)``."""
    out = np.zeros((rows.size, measured.shape[1]))
    for seg, first, record_first in record_runs(rows, measured.shape[0], starts):
        before = measured[max(record_first, first - max(1, n_init)) : first]
        finite = np.isfinite(before)
        count = finite.sum(axis=0)
        total = np.where(finite, before, 0.0).sum(axis=0)
        out[seg] = np.where(count > 0, total / np.maximum(count, 1), 0.0)
    return out


@dataclass(frozen=True)
class Choice:
    """The outcome of choosing accumulation: what was chosen, by whom, on what evidence."""

    accumulate: bool
    chosen_by: str  # "validation" or "user"
    scores: dict[str, float]  # candidate -> free-run NRMSE of the residual on validation
    validation_rows: int

    def to_dict(self) -> dict[str, object]:
        return {"accumulate": self.accumulate, **_evidence(self)}


def channel_nrmse(pred: np.ndarray, measured: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Per channel, RMSE / scale on the rows where both are finite (``inf`` where none is)."""
    err = pred - measured
    ok = np.isfinite(err)
    return np.array([
        np.sqrt(np.mean(err[ok[:, j], j] ** 2)) / scale[j] if ok[:, j].any() else np.inf
        for j in range(err.shape[1])
    ])  # fmt: skip


def free_run_nrmse(pred: np.ndarray, measured: np.ndarray, scale: np.ndarray) -> float:
    """Mean over channels of RMSE / scale on the rows where both are finite (channels in
    different units weigh alike)."""
    return float(np.mean(channel_nrmse(pred, measured, scale)))


def choose(scores: dict[bool, float], n_rows: int, by: str = "validation") -> Choice:
    """The candidate with the smaller validation error (accumulation on a tie)."""
    best = min(scores, key=lambda k: (scores[k], not k))
    named = {("accumulate" if k else "level"): v for k, v in scores.items()}
    return Choice(best, by, named, n_rows)


CORRECTION_NONE = "none"
"""The validation candidate "no correction": the physics alone (the residual taken as 0)."""
CORRECTION_HELD = "held"
"""The baseline of accumulated changes on the folds: the measured residual they start from,
held over the block (accumulation with no change predicted). A gain of accumulated changes
over the physics alone that this scores as well comes from that measured start, not from the
residual model, whose changes then only add drift."""
CORRECTION_OFFSET = "offset"
"""A correction of its own in a simulation: the physics plus the residual's mean over the
record's measured initialisation rows, held over the free run (no network). Where the
machine's mismatch is mostly an offset that differs from record to record (its load, its
temperature), the record's own measured start predicts it better than a net trained on other
records (the own-machine tutorial: test RMSE 0.184 rad/s against the residual level's 0.213).
Judged on folds of whole records as the net's candidates are, and offered where they offer
accumulated changes: a run's offset goes stale as the run grows, and a block of one record is
a shorter run than the model will make."""
CORRECTION_MARGIN = 0.01
"""A residual model is kept when its validation NRMSE is below the physics' by more than this
share: on a residual that is white noise, a net that learnt its training mean beats zero on a
short validation part by a few tenths of a percent, by chance."""


@dataclass(frozen=True)
class CorrectionChoice:
    """Whether a hybrid keeps its residual model: only when the corrected prediction beats the
    physics alone on the validation part of the training data (free-run / one-step NRMSE of
    the output, in the output's units over the measured residual's spread)."""

    kept: str  # "level", "accumulate", "residual", "offset" or CORRECTION_NONE
    chosen_by: str  # "validation" (tail), "validation folds", "user" or "no validation part"
    scores: dict[str, float]
    validation_rows: int
    wins: int | None = None  # folds on which the residual model beat the physics alone
    channels: tuple[bool, ...] = ()  # per output channel: corrected (empty: all as `correct`)
    channel_wins: tuple[int, ...] = ()  # per output channel: folds won (judged on folds)
    chosen_fold_nrmse: tuple[float, ...] = ()  # per fold: the prediction as chosen
    offset_channels: tuple[bool, ...] = ()  # per channel: the measured offset held, no net

    @property
    def correct(self) -> bool:
        return self.kept != CORRECTION_NONE

    def offset(self, n_channels: int) -> np.ndarray:
        """Per output channel, whether the measured offset held corrects it (instead of the
        residual model)."""
        if self.offset_channels:
            return np.array(self.offset_channels, dtype=bool)
        return np.zeros(n_channels, dtype=bool)

    def corrected(self, n_channels: int) -> np.ndarray:
        """Per output channel, whether its physics is corrected (by the residual model, or by
        the measured offset where :meth:`offset` says so)."""
        if self.channels:
            return np.array(self.channels, dtype=bool)
        return np.full(n_channels, self.correct)

    def to_dict(self, channel_names: Sequence[str] = ()) -> dict[str, object]:
        """As JSON; with several channels their verdicts and folds won, keyed by
        ``channel_names`` where given (else lists in channel order)."""
        out = {"kept": self.kept, **_evidence(self)}
        if self.wins is not None:
            out["wins"] = self.wins
        if any(self.offset_channels):
            out["offset"] = (dict(zip(channel_names, self.offset_channels, strict=True))
                             if channel_names else list(self.offset_channels))  # fmt: skip
        for key, values in (("corrected", self.channels), ("channel_wins", self.channel_wins)):
            if len(values) > 1:
                out[key] = (dict(zip(channel_names, values, strict=True)) if channel_names
                            else list(values))  # fmt: skip
        if self.chosen_fold_nrmse:
            out["chosen_fold_nrmse"] = [v if np.isfinite(v) else None
                                        for v in self.chosen_fold_nrmse]  # fmt: skip
        return out


def _evidence(choice: Choice | CorrectionChoice) -> dict[str, object]:
    """How a choice was made, as JSON: by whom, each candidate's validation NRMSE (null where
    not finite), on how many rows."""
    nrmse = {k: (v if np.isfinite(v) else None) for k, v in choice.scores.items()}
    return {"chosen_by": choice.chosen_by, "validation_nrmse": nrmse,
            "validation_rows": choice.validation_rows}  # fmt: skip


def choose_correction(
    candidate: str,
    correction: np.ndarray | None,
    residual: np.ndarray | None,
    test: bool = True,
) -> CorrectionChoice:
    """Keep the residual model's ``correction`` (validation rows, output units) only when it
    fits the measured ``residual`` there better than no correction does, by more than
    :data:`CORRECTION_MARGIN` (else: the physics alone). ``None``: no validation part, the correction is kept untested; ``test=False``: the
    user kept it (scores still recorded)."""
    if correction is None or residual is None or residual.shape[0] == 0:
        return CorrectionChoice(candidate, "no validation part", {}, 0)
    scale = np.nanstd(residual, axis=0)
    scale = np.where(np.isfinite(scale) & (scale > 0), scale, 1.0)
    with_model = channel_nrmse(correction, residual, scale)
    physics = channel_nrmse(np.zeros_like(residual), residual, scale)
    better = with_model < (1.0 - CORRECTION_MARGIN) * physics
    channels = tuple(bool(b) or not test for b in better)
    kept = candidate if any(channels) else CORRECTION_NONE
    scores = {CORRECTION_NONE: float(np.mean(physics)), candidate: float(np.mean(with_model))}
    return CorrectionChoice(kept, "validation" if test else "user", scores,
                            int(residual.shape[0]), channels=channels)  # fmt: skip


def choose_on_folds(candidate: str, folds: FoldScoresLike, test: bool = True) -> CorrectionChoice:
    """Keep ``candidate`` on each output channel only where it wins reliably on the blocked
    folds (:mod:`drafttwin.models.estimators.folds`): that channel below the physics alone on
    every fold, and on the mean over the folds by more than :data:`CORRECTION_MARGIN`;
    accumulated changes also below the measured residual held (:data:`CORRECTION_HELD`). The
    other channels predict their physics (a correction that helps three rollers may hurt the
    fourth). ``test=False``: the user kept it on every channel (scores still recorded)."""
    reliable = folds.channel_reliable(candidate)
    channels = tuple(bool(r) or not test for r in reliable)
    kept = candidate if any(channels) else CORRECTION_NONE
    scores = {CORRECTION_NONE: folds.mean(CORRECTION_NONE), candidate: folds.mean(candidate)}
    if candidate == "accumulate" and CORRECTION_HELD in folds.scores:
        scores[CORRECTION_HELD] = folds.mean(CORRECTION_HELD)
    return CorrectionChoice(kept, "validation folds" if test else "user", scores,
                            sum(folds.rows), wins=folds.wins(candidate), channels=channels,
                            channel_wins=tuple(folds.channel_wins(candidate)),
                            chosen_fold_nrmse=tuple(folds.chosen(candidate, channels)))  # fmt: skip


def with_offset(
    candidate: str, choice: CorrectionChoice, folds: FoldScoresLike
) -> CorrectionChoice:
    """``choice`` (the residual model's verdict per channel, :func:`choose_on_folds`) with the
    measured offset held (:data:`CORRECTION_OFFSET`) where the folds judged it: on a channel
    where it wins reliably against the physics alone (the same rule) and scores below the
    residual model's mean there, or where the residual model was refused, the offset
    corrects that channel instead."""
    if CORRECTION_OFFSET not in folds.scores or choice.chosen_by != "validation folds":
        return choice
    wins = np.array(folds.channel_reliable(CORRECTION_OFFSET), dtype=bool)
    net = np.array(choice.channels, dtype=bool)
    better = folds.channel_means(CORRECTION_OFFSET) < folds.channel_means(candidate)
    offset = wins & (~net | better)
    if not offset.any():
        return choice
    by_net = net & ~offset
    kept = candidate if by_net.any() else CORRECTION_OFFSET
    scores = {**choice.scores, CORRECTION_OFFSET: folds.mean(CORRECTION_OFFSET)}
    return CorrectionChoice(
        kept, choice.chosen_by, scores, choice.validation_rows,
        wins=choice.wins if by_net.any() else folds.wins(CORRECTION_OFFSET),
        channels=tuple(bool(v) for v in (by_net | offset)),
        channel_wins=choice.channel_wins,
        chosen_fold_nrmse=tuple(folds.chosen(candidate, by_net.tolist(), offset.tolist())),
        offset_channels=tuple(bool(v) for v in offset))  # fmt: skip


ONE_RECORD = "one record"
"""How the level is chosen without a contest when the training data are one record: its folds
are blocks of it, and a block's free run is shorter than the runs the model will make, while an
accumulated change's error grows with the run (on a 1000-row friction drive the thirds of its
one record chose accumulation, which then lost to the physics by 41 % on a record three times
as long as a fold; the level, tuned the same way, beat it by 21 %: docs/models.md, "Tuning")."""


def choose_accumulation_on_folds(candidates: Sequence[bool], folds: FoldScoresLike) -> Choice:
    """Accumulation or the level, on the blocked folds: of the candidates that win reliably
    (:func:`choose_on_folds`'s rule) the one with the lower fold mean; when neither or both
    do, the lower fold mean (accumulation on a tie). Both means are recorded."""
    means = {k: folds.mean(_name(k)) for k in candidates}
    pool = [k for k in candidates if folds.reliable(_name(k))] or list(candidates)
    best = min(pool, key=lambda k: (means[k], not k))
    return Choice(best, "validation folds", {_name(k): v for k, v in means.items()},
                  sum(folds.rows))  # fmt: skip


def _name(accumulate: bool) -> str:
    return "accumulate" if accumulate else "level"
