"""Causal change detection on block features, thresholds from healthy data.

Streams (linear in the five channel levels, see :data:`STREAMS`): the mean roller level, the
motor level, the belt (rollers minus motor) and each roller's parity (its level minus the
mean of the other three: positive drives keep it at zero unless that encoder is wrong).

Each stream is compared with a per-record baseline (the mean of the first ``reference_s``,
then an EWMA with time constant ``drift_tau_s`` while nothing is suspicious: slow thermal slip
and supply wander are normal running, not faults), whitened with an AR(1) model and a scale
fitted on healthy tuning records, and watched by a two-sided CUSUM (Page 1954) with reference
``k`` and a threshold ``h`` set by Siegmund's ARL approximation (Basseville & Nikiforov 1993)
so that all streams together raise ``far_per_day`` false alarms per 24 h of running.

Sensor validity rules run beside them: a channel that loses samples while the others keep
them, or repeats one value for longer than healthy tuning data ever did, is a sensor fault.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import brentq

from drafttwin.diagnosis.residuals import CHANNELS, BlockFeatures
from drafttwin.errors import ConfigError, DataError

STREAMS = ("rollers", "motor", "belt", *(f"parity_{c}" for c in CHANNELS[:4]))
SIEGMUND_OFFSET = 1.166


def stream_matrix() -> np.ndarray:
    """``(7, 5)``: each stream as a combination of the five channel levels."""
    a = np.zeros((len(STREAMS), len(CHANNELS)))
    a[0, :4] = 0.25
    a[1, 4] = 1.0
    a[2, :4], a[2, 4] = 0.25, -1.0
    for i in range(4):
        a[3 + i, :4] = -1.0 / 3.0
        a[3 + i, i] = 1.0
    return a


def siegmund_arl(h: float, k: float, mean: float = 0.0) -> float:
    """Average run length of a one-sided CUSUM on unit-variance data of ``mean``."""
    delta, b = mean - k, h + SIEGMUND_OFFSET
    if abs(delta) < 1e-12:
        return b * b
    return (math.exp(-2 * delta * b) + 2 * delta * b - 1) / (2 * delta * delta)


def threshold_for_arl(arl: float, k: float) -> float:
    """The CUSUM threshold ``h`` whose in-control ARL is ``arl`` (blocks)."""
    return float(brentq(lambda h: siegmund_arl(h, k) - arl, 0.0, 200.0))


@dataclass(frozen=True)
class Alarm:
    """One alarm: when, which test, which way, and the estimated change time."""

    time_s: float
    block: int
    test: str  # a stream name, or lost_<channel> / stuck_<channel>
    direction: int  # +1 up, -1 down, 0 for the sensor rules
    change_s: float  # estimated onset: the last time the CUSUM left zero


@dataclass
class Detection:
    """Result of :meth:`FaultDetector.run` on one record."""

    time_s: np.ndarray
    deviation: np.ndarray  # (blocks, 5) level minus baseline
    statistic: np.ndarray  # (blocks, streams) larger CUSUM side over h (1 = alarm)
    alarms: list[Alarm] = field(default_factory=list)
    baseline_at_alarm: np.ndarray | None = None

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
    """

    def __init__(self, far_per_day: float = 1.0, k: float = 0.5, reference_s: float = 15.0,
                 drift_tau_s: float = 120.0) -> None:  # fmt: skip
        for name, v in (("far_per_day", far_per_day), ("k", k), ("reference_s", reference_s),
                        ("drift_tau_s", drift_tau_s)):  # fmt: skip
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(
                    f"{name} = {v} is not > 0", where=name, fix="give a positive value"
                )
        self.far_per_day, self.k = far_per_day, k
        self.reference_s, self.drift_tau_s = reference_s, drift_tau_s

    # ---- fitting on healthy tuning records ----------------------------------------------
    def fit(self, healthy: Sequence[BlockFeatures]) -> FaultDetector:
        """Scale, AR(1) coefficient and threshold of each stream, sensor-rule limits."""
        if not healthy:
            raise DataError("no healthy tuning records", where="tuning", fix="give at least one")
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
        self.level_cov_ = np.cov(d_all.T)
        # each record's belt level against the physics (not its deviation): how far the
        # physics' belt creep is off on these machines (see locate.creep_mismatch)
        self.belt_level_ = np.array([np.nanmean(f.level @ a[2]) for f in healthy])
        s_all = d_all @ a.T
        x0 = np.vstack([p[0] for p in pairs])
        x1 = np.vstack([p[1] for p in pairs])
        good = np.isfinite(x0).all(axis=1) & np.isfinite(x1).all(axis=1)
        num = (x0[good] * x1[good]).sum(axis=0)
        self.phi_ = np.clip(num / np.maximum((x0[good] ** 2).sum(axis=0), 1e-300), 0.0, 0.95)
        self.sigma_ = np.maximum(s_all.std(axis=0), 1e-12)
        blocks_per_day = 86400.0 / self.block_s_
        arl = 2 * len(STREAMS) * blocks_per_day / self.far_per_day
        self.h_ = threshold_for_arl(arl, self.k)
        self.run_limit_ = 2 * np.max(np.vstack([f.run for f in healthy]), axis=0)
        self.lost_limit_ = np.max(np.vstack([f.lost for f in healthy]), axis=0) + 0.02
        return self

    def _reference_deviation(self, f: BlockFeatures) -> np.ndarray:
        n_ref = self._n_ref(f)
        base = np.nanmean(f.level[:n_ref], axis=0)
        return f.level[n_ref:] - base

    def _n_ref(self, f: BlockFeatures) -> int:
        n_ref = max(2, int(round(self.reference_s / f.block_s)))
        if len(f.level) <= n_ref:
            raise DataError(f"the record ({len(f.level) * f.block_s:g} s) is not longer than the "
                            f"reference window ({self.reference_s:g} s)", where="data",
                            fix="give a longer record or a shorter reference")  # fmt: skip
        return n_ref

    # ---- running causally over one record -----------------------------------------------
    def run(self, f: BlockFeatures, *, stop_at_first: bool = True) -> Detection:
        """Decide block by block; with ``stop_at_first=False`` every alarm episode is kept
        (after each, the CUSUMs restart from a new reference window, as at a record's
        start), for counting false alarms."""
        a = stream_matrix()
        n_ref = self._n_ref(f)
        base = np.nanmean(f.level[:n_ref], axis=0)
        nb, ns = len(f.level), len(STREAMS)
        dev = np.full((nb, len(CHANNELS)), np.nan)
        stat = np.zeros((nb, ns))
        det = Detection(f.time_s, dev, stat)
        up, down = np.zeros(ns), np.zeros(ns)
        up_start, down_start = np.zeros(ns, dtype=int), np.zeros(ns, dtype=int)
        prev = np.zeros(ns)
        scale = self.sigma_ * np.sqrt(1 - self.phi_**2)
        alpha = min(1.0, self.block_s_ / self.drift_tau_s)
        rebase: list[np.ndarray] = []
        rebasing = False
        for j in range(n_ref, nb):
            sensor = self._sensor_alarm(f, j)
            if sensor is not None:
                det.alarms.append(sensor)
                det.baseline_at_alarm = base.copy()
                if stop_at_first:
                    break
            lev = f.level[j]
            if not np.isfinite(lev).all():
                continue
            if rebasing:  # after an alarm: a new reference window, no decisions
                rebase.append(lev)
                if len(rebase) >= n_ref:
                    base, rebasing = np.mean(rebase, axis=0), False
                continue
            dev[j] = lev - base
            s = dev[j] @ a.T
            e = (s - self.phi_ * prev) / scale
            prev = s
            for arr, start, sign in ((up, up_start, 1.0), (down, down_start, -1.0)):
                was_zero = arr <= 0
                arr[:] = np.maximum(0.0, arr + sign * e - self.k)
                start[was_zero & (arr > 0)] = j
            stat[j] = np.maximum(up, down) / self.h_
            hit = np.flatnonzero(stat[j] >= 1.0)
            if hit.size:
                i = int(hit[np.argmax(stat[j, hit])])
                side = 1 if up[i] >= down[i] else -1
                begin = (up_start if side > 0 else down_start)[i]
                det.alarms.append(Alarm(float(f.time_s[j]), j, STREAMS[i], side,
                                        float(f.time_s[begin] - f.block_s)))  # fmt: skip
                det.baseline_at_alarm = base.copy()
                if stop_at_first:
                    break
                up[:], down[:], prev[:] = 0.0, 0.0, 0.0
                # restart like a record's start: the mean of the next reference window (one
                # block alone is too noisy a baseline: it set off a cascade of alarms)
                rebase, rebasing = [], True
                continue
            if stat[j].max() < 0.5:  # nothing suspicious: follow slow normal drift
                base = base + alpha * (lev - base)
        return det

    def _sensor_alarm(self, f: BlockFeatures, j: int) -> Alarm | None:
        for kind, values, limit in (("lost", f.lost[j], self.lost_limit_),
                                    ("stuck", f.run[j], self.run_limit_)):  # fmt: skip
            bad = np.flatnonzero(values > limit)
            if bad.size:
                ch = int(bad[np.argmax(values[bad] / np.maximum(limit[bad], 1e-12))])
                return Alarm(float(f.time_s[j]), j, f"{kind}_{CHANNELS[ch]}", 0,
                             float(f.time_s[j] - f.block_s))  # fmt: skip
        return None

    def describe(self) -> dict[str, Any]:
        """The fitted settings, JSON-able."""
        return {"far_per_day": self.far_per_day, "k": self.k, "h": self.h_,
                "block_s": self.block_s_, "reference_s": self.reference_s,
                "drift_tau_s": self.drift_tau_s, "belt_level": self.belt_level_.tolist(),
                "streams": {s: {"sigma": float(self.sigma_[i]), "phi": float(self.phi_[i])}
                            for i, s in enumerate(STREAMS)},
                "run_limit": dict(zip(CHANNELS, map(float, self.run_limit_), strict=True)),
                "lost_limit": dict(zip(CHANNELS, map(float, self.lost_limit_), strict=True))}  # fmt: skip
