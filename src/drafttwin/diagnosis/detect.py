"""Causal change detection on block features, thresholds from healthy data.

Streams (linear in the block features, see :data:`STREAMS` and :func:`stream_matrix`): the
mean roller level, the motor level, the belt (rollers minus motor), each roller's parity (its
level minus the mean of the other three: positive drives keep it at zero unless that encoder
is wrong), and the angle lag of the second, third and back roller behind the front (a worn
mesh's larger backlash or an elongated chain makes the driven roller trail by a fixed angle;
research/faults.md 2.2, 2.5).

Each stream is compared with a per-record baseline (the mean of the first ``reference_s``,
then an EWMA with time constant ``drift_tau_s`` while nothing is suspicious: slow thermal slip
and supply wander are normal running, not faults), whitened with an AR(1) model and a scale
fitted on healthy tuning records, and watched by a two-sided CUSUM (Page 1954) with reference
``k`` and a threshold ``h`` set by Siegmund's ARL approximation (Basseville & Nikiforov 1993)
so that all streams together raise ``far_per_day`` false alarms per 24 h of running.

Sensor validity rules run beside them: a channel that loses samples while the others keep
them is a sensor fault, and so is one that repeats one value while its angle lag moves (a
stale value: a counting encoder's identical counts leave the lag put, see
:mod:`~drafttwin.diagnosis.blocks`) for longer than any run in the healthy tuning data (and
than twice the longest such stale run there); the front roller and the motor are stuck too
when they repeat one value, lag moved or not, for longer than :data:`STILL_FACTOR` times
twice the longest run there (:data:`STILL_CHANNELS`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import brentq

from drafttwin.diagnosis.cusum import (
    FEATURES,
    STREAMS,
    Alarm,
    CusumState,
    feature_matrix,
    stream_matrix,
)
from drafttwin.diagnosis.residuals import CHANNELS, LAGGED, BlockFeatures
from drafttwin.diagnosis.walk import lag_walk
from drafttwin.errors import ConfigError, DataError

SIEGMUND_OFFSET = 1.166
JUMP_MARGIN = 2.0  # a lag's one-block jump rule: this many times the largest in tuning
LAG_TUNING_BLOCKS = 400
"""Decided blocks (after the reference windows, all tuning records together) the angle-lag
streams need before they are watched. Their slow wander (long-run variance, random walk) is
measured badly on less: detectors fitted on one machine's first 300, 420, 540 and 630 s,
each tried on another 10-min record of the same machine (8 plant machines, both ways, 2.7 h),
raised 19, 8, 6 and 4 lag alarms at a budget of 100 per day (9 expected), and 22, 7, 6 and 4
at 1000 per day (about 110 expected, the levels' about 65); on 2 x 100-s synthetic records 6
of 20 healthy records alarmed (2026-11-28)."""
LEVEL_TUNING_BLOCKS = 285
"""Decided blocks (after the reference windows, all tuning records together) below which the
level streams' thresholds are said to be unsure: the drafting force wanders over tens of
seconds and the supply over minutes, and less healthy running does not show how far. On 8
plant machines a healthy 60-s record (seed 3) alarmed on the belt stream with thresholds from
another healthy record of the machine of 60 s (7 of 7), 120 s (4 of 4) and 180 s (4 of 4),
and on none with 300 s (0 of 4; 2026-11-30), the reference windows of 15 s included."""
STILL_FACTOR = 4.0  # any run is stuck past this many times the run limit: a counting
# encoder repeats a count for L samples when its count per sample lies within about 1/L of a
# whole number, so healthy runs are long-tailed and differ from machine to machine and speed
# to speed (6-22 samples in 60 s of a roller; 30 after a belt wear slowed the machine, against
# 6 in its 30-s tuning record); only a run that moves the lag is evidence by itself
STILL_CHANNELS = np.array([True, False, False, False, True])
"""Channels whose runs :data:`STILL_FACTOR` judges by length alone: the front roller, whose
held value moves the slower rollers' lags by its ratio (0.2-0.24) only, and the motor (no
lag). A lagged roller's run that leaves its lag put is a right reading however long: after a
belt wear slowed a machine, the second roller's count sat on a whole number for 62 samples
at a time on the live plant (a run limit of 15) and the rule called it stuck."""


def siegmund_arl(h: float, k: float, mean: float = 0.0) -> float:
    """Average run length of a one-sided CUSUM on unit-variance data of ``mean``."""
    delta, b = mean - k, h + SIEGMUND_OFFSET
    if abs(delta) < 1e-12:
        return b * b
    return (math.exp(-2 * delta * b) + 2 * delta * b - 1) / (2 * delta * delta)


def threshold_for_arl(arl: float, k: float) -> float:
    """The CUSUM threshold ``h`` whose in-control ARL is ``arl`` (blocks)."""
    return float(brentq(lambda h: siegmund_arl(h, k) - arl, 0.0, 200.0))


@dataclass
class Detection:
    """Result of :meth:`FaultDetector.run` on one record: per block each rule's statistic
    over its limit (1 = alarm), so a page can show the rule that fired with its own."""

    time_s: np.ndarray
    deviation: np.ndarray  # (blocks, 8) features (FEATURES) minus baseline
    statistic: np.ndarray  # (blocks, streams) larger CUSUM side over h (1 = alarm)
    alarms: list[Alarm] = field(default_factory=list)
    baseline_at_alarm: np.ndarray | None = None
    jump: np.ndarray | None = None  # (blocks, streams) |innovation| over the jump limit (lags)
    sensor: np.ndarray | None = None  # (blocks, 2 x channels) lost, then run, over its limit

    @property
    def first(self) -> Alarm | None:
        return self.alarms[0] if self.alarms else None


class FaultDetector:
    """Two-sided CUSUM per stream plus sensor rules, scikit-learn style.

    Args:
        far_per_day: false alarms allowed per 24 h of healthy running, all streams together.
        k: CUSUM reference (half the shift, in whitened units, it is tuned for).
        reference_s: start of each record used as its baseline (no decisions there).
        drift_tau_s: time constant of the baseline's tracking of slow normal drift.
        long_run_blocks: lags (blocks) of the long-run variance that widens each stream's
            scale (0: off); see :meth:`_long_run_factor`.
    """

    def __init__(self, far_per_day: float = 1.0, k: float = 0.5, reference_s: float = 15.0,
                 drift_tau_s: float = 120.0, long_run_blocks: int = 60) -> None:  # fmt: skip
        for name, v in (("far_per_day", far_per_day), ("k", k), ("reference_s", reference_s),
                        ("drift_tau_s", drift_tau_s)):  # fmt: skip
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(
                    f"{name} = {v} is not > 0", where=name, fix="give a positive value"
                )
        self.far_per_day, self.k = far_per_day, k
        self.reference_s, self.drift_tau_s = reference_s, drift_tau_s
        if long_run_blocks < 0:
            raise ConfigError(f"long_run_blocks = {long_run_blocks} is < 0", where="long_run_blocks",
                              fix="give 0 (off) or a number of blocks, e.g. 60")  # fmt: skip
        self.long_run_blocks = long_run_blocks

    # ---- fitting on healthy tuning records ----------------------------------------------
    def fit(self, healthy: Sequence[BlockFeatures]) -> FaultDetector:
        """Scale, AR(1) coefficient and threshold of each stream, sensor-rule limits."""
        if not healthy:
            raise DataError("no healthy tuning records", where="tuning", fix="give at least one")
        healthy = self._steady_runs(healthy)
        self.block_s_ = healthy[0].block_s
        a = stream_matrix()
        devs, pairs = [], []
        for f in healthy:
            d = self._reference_deviation(f)
            devs.append(d)
            s = d @ a.T
            pairs.append((s[:-1], s[1:]))
        d_all = np.vstack(devs)
        d_all = d_all[np.isfinite(d_all).all(axis=1)]
        if len(d_all) < 10:
            raise DataError("healthy tuning data too short (fewer than 10 blocks after the "
                            "reference window)", where="tuning", fix="give longer records")  # fmt: skip
        self.tuning_blocks_ = len(d_all)
        self.feature_cov_ = np.cov(d_all.T)
        self.level_cov_ = self.feature_cov_[: len(CHANNELS), : len(CHANNELS)]
        # each record's belt level against the physics (not its deviation): how far the
        # physics' belt creep is off on these machines (see locate.creep_mismatch)
        self.belt_level_ = np.array([np.nanmean(feature_matrix(f) @ a[2]) for f in healthy])
        s_all = d_all @ a.T
        x0 = np.vstack([p[0] for p in pairs])
        x1 = np.vstack([p[1] for p in pairs])
        good = np.isfinite(x0).all(axis=1) & np.isfinite(x1).all(axis=1)
        num = (x0[good] * x1[good]).sum(axis=0)
        self.phi_ = np.clip(num / np.maximum((x0[good] ** 2).sum(axis=0), 1e-300), 0.0, 0.95)
        self.sigma_ = np.maximum(s_all.std(axis=0), 1e-12)
        self.long_run_ = self._long_run_factor([p[1] for p in pairs])
        self.lag_walk_ = lag_walk([np.asarray(f.lags, dtype=np.float64) for f in healthy])
        self.watched_ = self._watched(healthy)
        self.jump_limit_ = self._jump_limit(x0[good], x1[good])
        blocks_per_day = 86400.0 / self.block_s_
        arl = 2 * len(STREAMS) * blocks_per_day / self.far_per_day
        self.h_ = threshold_for_arl(arl, self.k)
        self.run_limit_ = 2 * np.max(np.vstack([f.run for f in healthy]), axis=0)
        # a stale run is stuck past twice the longest in tuning (none: 1) and past the longest
        # healthy run: a gain fault walks the lag too, and a run that starts with it moved
        # nothing before it (runs of a gained channel are as long as a healthy one's)
        stale = 2 * np.max(np.vstack([f.stale_runs for f in healthy]), axis=0)
        self.stale_limit_ = np.maximum(stale, self.run_limit_ / 2)
        self.lost_limit_ = np.max(np.vstack([f.lost for f in healthy]), axis=0) + 0.02
        return self

    def _steady_runs(self, healthy: Sequence[BlockFeatures]) -> list[BlockFeatures]:
        """The tuning records' stretches of steady running, each a record of its own with its
        reference window, as the decisions judge them (a stretch not longer than the
        reference window left out); a record that is steady throughout stays whole."""
        out: list[BlockFeatures] = []
        for f in healthy:
            if f.steady_blocks.all():  # whole (a short one is refused as before, by _n_ref)
                out.append(f)
                continue
            out += [r for r in f.steady_runs()
                    if len(r.level) > self.reference_blocks(r.block_s)]  # fmt: skip
        if not out:
            raise DataError("the healthy tuning records hold no steady running longer than the "
                            f"reference window ({self.reference_s:g} s): they start, stop or "
                            "change speed throughout", where="tuning",
                            fix="give records of steady running")  # fmt: skip
        return out

    def _jump_limit(self, x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
        """Per stream, the one-block jump rule's limit on the AR(1) innovation (in units of
        its own scale, not widened): :data:`JUMP_MARGIN` times the largest in the tuning
        records, on the angle lags only (0 elsewhere: no rule). A worn mesh steps its lag
        at once; whitened with a coefficient near its 0.95 cap, the step is all in one
        block's innovation (then 5 % of it per block), which the CUSUM, widened for the
        lags' slow wander, does not reach. The limit comes from healthy data like the
        sensor rules' (twice the longest healthy run)."""
        unit = self.sigma_ * np.sqrt(1 - self.phi_**2)
        e = np.abs(x1 - self.phi_ * x0) / unit
        top = e.max(axis=0) if len(e) else np.zeros(len(STREAMS))
        return np.array([JUMP_MARGIN * top[i] if s.startswith("lag_") else 0.0
                         for i, s in enumerate(STREAMS)])  # fmt: skip

    def _watched(self, healthy: Sequence[BlockFeatures]) -> np.ndarray:
        """Which streams decide: the angle lags only when a tuning record runs at least
        :attr:`long_run_blocks` blocks past its reference window and all together hold
        :data:`LAG_TUNING_BLOCKS` decided blocks. Their slow wander is what the long-run
        factor and the walk measure; shorter records cannot see it, and the lags then raise
        false alarms (on 2 x 10-s tuning records, one healthy replay in three)."""
        after = [len(f.level) - self._n_ref(f) for f in healthy]
        lags_ok = self.long_run_blocks == 0 or (
            max(after) >= self.long_run_blocks and sum(after) >= LAG_TUNING_BLOCKS
        )
        return np.array([lags_ok or not s.startswith("lag_") for s in STREAMS])

    @property
    def lags_watched(self) -> bool:
        """The angle-lag streams decide (see :meth:`_watched`)."""
        return bool(self.watched_[STREAMS.index(f"lag_{LAGGED[0]}")])

    def lags_note(self) -> str | None:
        """A line for the user when the angle lags are not watched, else ``None``."""
        if self.lags_watched:
            return None
        need = self.reference_s + max(self.long_run_blocks, LAG_TUNING_BLOCKS) * self.block_s_
        return (
            f"angle lags not watched (gear wear, chain elongation): the healthy records "
            f"are too short to measure their slow wander; give one of at least {need:.0f} s "
            f"(or several with {LAG_TUNING_BLOCKS * self.block_s_:.0f} s of running in all past "
            f"their {self.reference_s:g}-s reference windows)"
        )

    def levels_note(self) -> str | None:
        """A line for the user when the healthy running the thresholds come from is short
        (:data:`LEVEL_TUNING_BLOCKS`), else ``None``."""
        blocks = getattr(self, "tuning_blocks_", None)
        if blocks is None or blocks >= LEVEL_TUNING_BLOCKS:
            return None
        need = self.reference_s + LEVEL_TUNING_BLOCKS * self.block_s_
        return (
            f"the thresholds come from {blocks * self.block_s_:.0f} s of healthy running past "
            f"the reference window: too short to show how far the drafting force and the "
            f"supply wander, so a healthy record may raise an alarm (measured: every plant "
            f"machine tried did on 60-180 s, none on {need:.0f} s); give a healthy record of "
            f"at least {need:.0f} s (or several with {LEVEL_TUNING_BLOCKS * self.block_s_:.0f} "
            f"s past their reference windows in all)"
        )

    def _reference_deviation(self, f: BlockFeatures) -> np.ndarray:
        n_ref = self._n_ref(f)
        x = feature_matrix(f)
        deviation: np.ndarray = x[n_ref:] - np.nanmean(x[:n_ref], axis=0)
        return deviation

    def _long_run_factor(self, streams: Sequence[np.ndarray]) -> np.ndarray:
        """Long-run variance of the AR(1)-whitened streams over their variance, pooled over
        the tuning records (Bartlett weights up to :attr:`long_run_blocks` lags; at least
        1). Slow wander that an AR(1) does not whiten (supply, drafting force over minutes)
        leaves the innovations correlated; the CUSUM sums them, so its random walk grows
        with the long-run variance, which Siegmund's approximation then needs as its unit."""
        lags = self.long_run_blocks
        if lags < 1:
            return np.ones(len(STREAMS))
        num, den = np.zeros((lags, len(STREAMS))), np.zeros(len(STREAMS))
        for s in streams:
            e = s[1:] - self.phi_ * s[:-1]
            e = e - np.nanmean(e, axis=0)
            e = np.where(np.isfinite(e), e, 0.0)
            den += (e**2).sum(axis=0)
            for k in range(1, min(lags, len(e) - 1) + 1):
                num[k - 1] += (e[k:] * e[:-k]).sum(axis=0)
        rho = num / np.maximum(den, 1e-300)
        weights = 1.0 - np.arange(1, lags + 1) / (lags + 1.0)
        factor: np.ndarray = np.maximum(1.0, 1.0 + 2.0 * (weights[:, None] * rho).sum(axis=0))
        return factor

    def reference_blocks(self, block_s: float) -> int:
        """Blocks of ``block_s`` seconds in the reference window (at least 2)."""
        return max(2, int(round(self.reference_s / block_s)))

    @property
    def drift_alpha(self) -> float:
        """The baseline's EWMA weight per block while it follows slow drift."""
        return min(1.0, self.block_s_ / self.drift_tau_s)

    def _n_ref(self, f: BlockFeatures) -> int:
        n_ref = self.reference_blocks(f.block_s)
        if len(f.level) <= n_ref:
            raise DataError(f"the record ({len(f.level) * f.block_s:g} s) is not longer than the "
                            f"reference window ({self.reference_s:g} s)", where="data",
                            fix="give a longer record (the first reference_s seconds of each "
                            "record are its baseline, not watched)")  # fmt: skip
        return n_ref

    # ---- running causally over one record -----------------------------------------------
    def run(self, f: BlockFeatures, *, stop_at_first: bool = True) -> Detection:
        """Decide block by block; with ``stop_at_first=False`` every alarm episode is kept
        (after each, the CUSUMs restart from a new reference window, as at a record's
        start), for counting false alarms."""
        n_ref = self._n_ref(f)
        x = feature_matrix(f)
        nb, ns = len(x), len(STREAMS)
        dev = np.full((nb, len(FEATURES)), np.nan)
        stat = np.zeros((nb, ns))
        jump = np.zeros((nb, ns))
        stale, steady = f.stale_runs, f.steady_blocks
        det = Detection(f.time_s, dev, stat, jump=jump,
                        sensor=self.sensor_ratio(f.lost, f.run, stale))  # fmt: skip
        state = CusumState(self, n_ref, f.block_s)
        for j in range(nb):
            alarms = state.update(float(f.time_s[j]), x[j], f.lost[j], f.run[j], stale[j],
                                  bool(steady[j]))  # fmt: skip
            sensor_first = stop_at_first and alarms and alarms[0].direction == 0
            if state.deviation is not None and not sensor_first:  # (it stopped before them)
                dev[j], stat[j] = state.deviation, state.statistic
                jump[j] = state.jump_ratio
            if alarms:
                det.baseline_at_alarm = state.baseline_at_alarm
                det.alarms.extend(alarms[:1] if stop_at_first else alarms)
                if stop_at_first:
                    break
        return det

    def sensor_alarm(self, time_s: float, block: int, lost: np.ndarray, run: np.ndarray,
                     stale: np.ndarray, block_s: float) -> Alarm | None:  # fmt: skip
        """The sensor rules on one block (its lost shares, longest runs and longest stale
        runs per channel): a channel losing samples alone, or stuck."""
        ratio = self.sensor_ratio(lost, run, stale).reshape(2, len(CHANNELS))
        for kind, values in zip(("lost", "stuck"), ratio, strict=True):
            bad = np.flatnonzero(values > 1.0)
            if bad.size:
                ch = int(bad[np.argmax(values[bad])])
                return Alarm(time_s, block, f"{kind}_{CHANNELS[ch]}", 0, time_s - block_s,
                             "sensor")  # fmt: skip
        return None

    def sensor_ratio(self, lost: np.ndarray, run: np.ndarray, stale: np.ndarray) -> np.ndarray:
        """The sensor rules' statistics over their limits, ``(..., 2 x channels)``: each
        channel's lost fraction, then its longest stale run over its limit, or where larger on
        :data:`STILL_CHANNELS` its longest run over :data:`STILL_FACTOR` times the run limit (a
        rule fires above 1)."""
        still = np.asarray(run) / np.maximum(STILL_FACTOR * self.run_limit_, 1e-12)
        stuck = np.maximum(np.asarray(stale) / np.maximum(self.stale_limit_, 1e-12),
                           np.where(STILL_CHANNELS, still, 0.0))  # fmt: skip
        return np.concatenate([lost / np.maximum(self.lost_limit_, 1e-12), stuck], axis=-1)

    def describe(self) -> dict[str, Any]:
        """The fitted settings, JSON-able."""
        return {"far_per_day": self.far_per_day, "k": self.k, "h": self.h_,
                "block_s": self.block_s_, "reference_s": self.reference_s,
                "drift_tau_s": self.drift_tau_s, "belt_level": self.belt_level_.tolist(),
                "long_run_blocks": self.long_run_blocks,
                "streams": {s: {"sigma": float(self.sigma_[i]), "phi": float(self.phi_[i]),
                                "long_run_factor": float(self.long_run_[i]),
                                "watched": bool(self.watched_[i]),
                                "jump_limit": float(self.jump_limit_[i])}
                            for i, s in enumerate(STREAMS)},
                "run_limit": dict(zip(CHANNELS, map(float, self.run_limit_), strict=True)),
                "stale_limit": dict(zip(CHANNELS, map(float, self.stale_limit_), strict=True)),
                "lost_limit": dict(zip(CHANNELS, map(float, self.lost_limit_), strict=True)),
                "lag_walk_mrad2_per_block": dict(zip(LAGGED, map(float, np.diag(self.lag_walk_)),
                                                     strict=True))}  # fmt: skip

    # ---- stored with a model (drafttwin twin fit-detector) -----------------------------
    def to_state(self) -> dict[str, Any]:
        """Everything :meth:`from_state` needs, JSON-able (the settings and fitted values)."""
        return {"far_per_day": self.far_per_day, "k": self.k, "reference_s": self.reference_s,
                "drift_tau_s": self.drift_tau_s, "block_s": self.block_s_, "h": self.h_,
                "feature_cov": self.feature_cov_.tolist(), "belt_level": self.belt_level_.tolist(),
                "phi": self.phi_.tolist(), "sigma": self.sigma_.tolist(),
                "long_run_blocks": self.long_run_blocks, "long_run": self.long_run_.tolist(),
                "watched": self.watched_.tolist(), "jump_limit": self.jump_limit_.tolist(),
                "run_limit": self.run_limit_.tolist(), "lost_limit": self.lost_limit_.tolist(),
                "stale_limit": self.stale_limit_.tolist(), "lag_walk": self.lag_walk_.tolist(),
                # a detector read from an older file, or combined from others, has no count
                **({} if (blocks := getattr(self, "tuning_blocks_", None)) is None
                   else {"tuning_blocks": blocks})}  # fmt: skip

    @classmethod
    def from_state(cls, state: dict[str, Any], source: str = "detector") -> FaultDetector:
        """A fitted detector from :meth:`to_state`, every value checked (shape, finite, > 0
        where a scale or threshold)."""
        try:
            det = cls(float(state["far_per_day"]), float(state["k"]),
                      float(state["reference_s"]), float(state["drift_tau_s"]),
                      int(state["long_run_blocks"]))  # fmt: skip
            ns, nc, nf = len(STREAMS), len(CHANNELS), len(FEATURES)
            det.block_s_ = _positive(state["block_s"], "block_s", source)
            det.h_ = _positive(state["h"], "h", source)
            det.feature_cov_ = _array(state["feature_cov"], (nf, nf), "feature_cov", source)
            det.level_cov_ = det.feature_cov_[:nc, :nc]
            det.long_run_ = _array(state["long_run"], (ns,), "long_run", source)
            det.jump_limit_ = _array(state["jump_limit"], (ns,), "jump_limit", source)
            det.watched_ = np.asarray(state["watched"], dtype=bool)
            if det.watched_.shape != (ns,):
                raise ValueError(f"watched has shape {det.watched_.shape}, not ({ns},)")
            det.belt_level_ = np.asarray(state["belt_level"], dtype=np.float64)
            det.phi_ = _array(state["phi"], (ns,), "phi", source)
            det.sigma_ = _array(state["sigma"], (ns,), "sigma", source)
            det.run_limit_ = _array(state["run_limit"], (nc,), "run_limit", source)
            # a detector fitted before 2026-11-29 judged every run by its length alone
            det.stale_limit_ = _array(state.get("stale_limit", state["run_limit"]), (nc,),
                                      "stale_limit", source)  # fmt: skip
            det.lost_limit_ = _array(state["lost_limit"], (nc,), "lost_limit", source)
            if "tuning_blocks" in state:  # written since 2026-11-30
                det.tuning_blocks_ = int(state["tuning_blocks"])
            nl = len(LAGGED)  # a state written before the walk was measured: none
            det.lag_walk_ = _array(
                state.get("lag_walk", np.zeros((nl, nl))), (nl, nl), "lag_walk", source
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(f"not a fitted detector ({type(exc).__name__}: {exc})",
                            source=source, fix="fit it again (drafttwin twin fit-detector)") from None  # fmt: skip
        if ((det.sigma_ <= 0).any() or not (det.phi_ >= 0).all() or not (det.phi_ < 1).all()
                or (det.long_run_ < 1).any() or (det.jump_limit_ < 0).any()):  # fmt: skip
            raise DataError("detector scales out of range (sigma > 0, 0 <= phi < 1, long_run >= 1, "
                            "jump_limit >= 0)",
                            source=source, fix="fit it again (drafttwin twin fit-detector)")  # fmt: skip
        if (np.linalg.eigvalsh(0.5 * (det.lag_walk_ + det.lag_walk_.T)) < -1e-9).any():
            raise DataError("detector lag_walk is not a covariance (a negative eigenvalue)",
                            source=source, fix="fit it again (drafttwin twin fit-detector)")  # fmt: skip
        if det.belt_level_.ndim != 1 or not np.isfinite(det.belt_level_).all():
            raise DataError("detector belt levels not finite", source=source,
                            fix="fit it again (drafttwin twin fit-detector)")  # fmt: skip
        return det


def _positive(v: Any, name: str, source: str) -> float:
    x = float(v)
    if not (math.isfinite(x) and x > 0):
        raise DataError(f"{name} = {x} is not > 0", source=source, where=name,
                        fix="fit it again (drafttwin twin fit-detector)")  # fmt: skip
    return x


def _array(v: Any, shape: tuple[int, ...], name: str, source: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    if a.shape != shape or not np.isfinite(a).all():
        raise DataError(f"{name} has shape {a.shape} (expected {shape}) or is not finite",
                        source=source, where=name, fix="fit it again (drafttwin twin fit-detector)")  # fmt: skip
    return a
