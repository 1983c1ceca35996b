"""A machine learns its own healthy state: the detector fitted on its first minutes.

A machine new to the twin (or after maintenance) runs in a *learning state*: its blocks are
collected, no fault is decided, and once it has run long enough the detector
(:class:`~drafttwin.diagnosis.detect.FaultDetector`) is fitted on them. How long that is
comes from what the detector needs, measured on the plant (docs/faults.md, "Learning"):

* alone, :data:`LEARN_S`: the angle-lag streams need about 400 decided blocks
  (:data:`~drafttwin.diagnosis.detect.LAG_TUNING_BLOCKS`); detectors fitted on 2 or 5 min
  of one machine raised several times their false-alarm budget on its later running;
* on top of a *prior* (a detector fitted on longer healthy running of machines of the type,
  ``drafttwin twin fit-detector``), :data:`LEARN_WITH_PRIOR_S`: the level streams settle in
  two minutes, and the machine's detector is the two combined (:func:`combine`): per stream
  the prior's dynamics (its AR(1) coefficient and long-run factor, which two minutes
  underestimate) with the larger SD, the larger limits, so a machine noisier than the fleet
  is judged by its own noise and a quieter one by the fleet's (never less conservative than
  the prior); the machine's own belt level (the physics' creep mismatch on it) goes to the
  ranking.
"""

from __future__ import annotations

import copy
import math

import numpy as np

from drafttwin.diagnosis.blocks import BlockRow
from drafttwin.diagnosis.detect import FaultDetector
from drafttwin.diagnosis.residuals import BlockFeatures
from drafttwin.errors import ConfigError

LEARN_S = 600.0
"""Running time a machine learns alone, s."""
LEARN_WITH_PRIOR_S = 120.0
"""Running time a machine learns on top of a prior that watches the angle lags, s."""
MIN_DECIDED = 10
"""Fewest blocks past the reference windows a detector is fitted on (its own minimum)."""


def learn_time(prior: FaultDetector | None) -> float:
    """The learning time a machine needs with ``prior`` (or none), s."""
    return LEARN_WITH_PRIOR_S if prior is not None and prior.lags_watched else LEARN_S


class Learner:
    """The blocks of one machine's learning state, fitted into its detector when enough.

    Args:
        learn_s: running time to learn, s (blocks with every feature measured; each run
            after a stop or a gap is a record of its own, its first ``reference_s`` its
            reference).
        prior: a detector to combine with (:func:`combine`), or ``None``.
        far_per_day: the false-alarm budget of the learned detector (the prior's, with one).
    """

    def __init__(self, learn_s: float, prior: FaultDetector | None = None,
                 far_per_day: float = 1.0) -> None:  # fmt: skip
        if not (math.isfinite(learn_s) and learn_s > 0):
            raise ConfigError(f"learning time {learn_s} s is not > 0", where="--learn",
                              fix=f"give seconds, e.g. {LEARN_S:g}")  # fmt: skip
        self.learn_s, self.prior = float(learn_s), prior
        self.far_per_day = prior.far_per_day if prior is not None else far_per_day
        self.records: list[list[BlockRow]] = [[]]
        self.block_s: float | None = None

    @property
    def blocks(self) -> int:
        return sum(len(r) for r in self.records)

    @property
    def learned_s(self) -> float:
        """Running time collected so far, s."""
        return self.blocks * (self.block_s or 0.0)

    @property
    def progress(self) -> float:
        """Share of the learning time collected, 0-1."""
        return min(1.0, self.learned_s / self.learn_s)

    def new_record(self) -> None:
        """A stop or a gap: the next blocks are another run."""
        if self.records[-1]:
            self.records.append([])

    def add(self, row: BlockRow, block_s: float) -> FaultDetector | None:
        """One block; the fitted detector once the learning time is reached (else None)."""
        self.block_s = block_s
        if not row.steady:  # a start, a stop, a speed change: the next steady block begins a run
            self.new_record()
            return None
        if not np.isfinite(row.features).all():  # a stop or a dropout: not running
            return None
        self.records[-1].append(row)
        if self.learned_s < self.learn_s - 1e-9:
            return None
        return self.fit()

    def fit(self) -> FaultDetector | None:
        """The detector of the blocks so far (None: no run is longer than its reference)."""
        assert self.block_s is not None
        proto = FaultDetector(far_per_day=self.far_per_day) if self.prior is None else self.prior
        n_ref = proto.reference_blocks(self.block_s)
        runs = [BlockFeatures.from_rows(r, self.block_s) for r in self.records if len(r) > n_ref]
        if sum(len(r.level) - n_ref for r in runs) < MIN_DECIDED:
            return None
        own = FaultDetector(far_per_day=self.far_per_day, k=proto.k,
                            reference_s=proto.reference_s, drift_tau_s=proto.drift_tau_s,
                            long_run_blocks=proto.long_run_blocks).fit(runs)  # fmt: skip
        return own if self.prior is None else combine(own, self.prior)


def combine(own: FaultDetector, prior: FaultDetector) -> FaultDetector:
    """A machine's detector from its own short learning (``own``) and a ``prior`` fitted on
    longer running of machines of its type: per stream the prior's AR(1) coefficient and
    long-run factor with the larger SD (the machine's own all three where only it watches), the
    larger jump, stuck and lost limits and lag walk, each feature's larger SD on the prior's
    correlations, a stream watched where either watches it (its scale then from one that
    does), and the machine's own belt level (the ranking's creep mismatch on it)."""
    if abs(own.block_s_ - prior.block_s_) > 1e-9:
        raise ConfigError(f"the prior's blocks are {prior.block_s_:g} s, the machine's "
                          f"{own.block_s_:g} s", where="--detector",
                          fix="fit the prior with the twin's block length")  # fmt: skip
    out = copy.deepcopy(own)
    # A stream's dynamics (AR(1) coefficient, long-run factor) need long running: two
    # minutes underestimate both (the rollers' coefficient 0.78 against the fleet's 0.92),
    # and a CUSUM whitened with them sums what is left of the slow wander into false alarms
    # (3 in 12 h of the live benchmark). Where the prior watches a stream its dynamics
    # stand; the machine's own noise can only widen the stream's SD.
    theirs = prior.watched_
    out.phi_ = np.where(theirs, prior.phi_, own.phi_)
    out.long_run_ = np.where(theirs, prior.long_run_, own.long_run_)
    out.sigma_ = np.where(theirs, np.maximum(own.sigma_, prior.sigma_), own.sigma_)
    out.watched_ = own.watched_ | prior.watched_
    out.jump_limit_ = np.maximum(own.jump_limit_, prior.jump_limit_)
    out.run_limit_ = np.maximum(own.run_limit_, prior.run_limit_)
    out.stale_limit_ = np.maximum(own.stale_limit_, prior.stale_limit_)
    out.lost_limit_ = np.maximum(own.lost_limit_, prior.lost_limit_)
    walks = (own.lag_walk_, prior.lag_walk_)
    out.lag_walk_ = max(walks, key=lambda w: float(np.trace(w))).copy()
    sd = np.sqrt(np.maximum(np.diag(own.feature_cov_), np.diag(prior.feature_cov_)))
    psd = np.sqrt(np.maximum(np.diag(prior.feature_cov_), 1e-300))
    corr = prior.feature_cov_ / np.outer(psd, psd)
    out.feature_cov_ = corr * np.outer(sd, sd)
    out.level_cov_ = out.feature_cov_[: own.level_cov_.shape[0], : own.level_cov_.shape[1]]
    out.belt_level_ = own.belt_level_.copy()
    return out


__all__ = ["LEARN_S", "LEARN_WITH_PRIOR_S", "Learner", "combine", "learn_time"]
