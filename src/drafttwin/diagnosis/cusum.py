"""The detector's streams and its per-block decisions.

:data:`STREAMS` are linear in the block features (:data:`FEATURES`, :func:`stream_matrix`);
:class:`CusumState` decides one block at a time, for a whole record
(:meth:`~drafttwin.diagnosis.detect.FaultDetector.run`) and for the live twin alike: one
implementation of the decisions. The detector it holds
(:class:`~drafttwin.diagnosis.detect.FaultDetector`) gives the fitted scales, thresholds and
sensor rules.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from drafttwin.diagnosis.residuals import CHANNELS, LAGGED, BlockFeatures

STREAMS = ("rollers", "motor", "belt", *(f"parity_{c}" for c in CHANNELS[:4]),
           *(f"lag_{c}" for c in LAGGED))  # fmt: skip
FEATURES = (*CHANNELS, *(f"lag_{c}" for c in LAGGED))
"""The block feature vector: five relative levels, then three angle lags (mrad)."""


def stream_matrix() -> np.ndarray:
    """``(10, 8)``: each stream as a combination of the block features (:data:`FEATURES`)."""
    a = np.zeros((len(STREAMS), len(FEATURES)))
    a[0, :4] = 0.25
    a[1, 4] = 1.0
    a[2, :4], a[2, 4] = 0.25, -1.0
    for i in range(4):
        a[3 + i, :4] = -1.0 / 3.0
        a[3 + i, i] = 1.0
    for i in range(len(LAGGED)):
        a[7 + i, len(CHANNELS) + i] = 1.0
    return a


def feature_matrix(f: BlockFeatures) -> np.ndarray:
    """``(blocks, 8)``: the levels and the angle lags of each block."""
    return np.hstack([f.level, f.lags])


RULES = {
    "cusum": "CUSUM: the stream's whitened deviation summed past its threshold h",
    "jump": "lag jump: one block's innovation of an angle lag past its jump limit",
    "sensor": "sensor rule: a channel losing samples alone, or repeating one value",
}
"""The rules that raise an alarm (:attr:`Alarm.rule`), each with its own statistic and limit
(:class:`Detection`)."""


@dataclass(frozen=True)
class Alarm:
    """One alarm: when, which test, which way, the estimated change time, and the rule."""

    time_s: float
    block: int
    test: str  # a stream name, or lost_<channel> / stuck_<channel>
    direction: int  # +1 up, -1 down, 0 for the sensor rules
    change_s: float  # estimated onset: the last time the CUSUM left zero
    rule: str = "cusum"  # which rule fired, a key of RULES


class FittedDetector(Protocol):
    """What :class:`CusumState` reads of a fitted
    :class:`~drafttwin.diagnosis.detect.FaultDetector` (a protocol, so that the decisions do
    not import the detector that runs them): per stream its AR(1) coefficient, scale,
    long-run factor, whether it is watched, its jump limit; the CUSUM's ``k`` and ``h_``; the
    baseline's drift weight, and the sensor rules."""

    k: float
    h_: float
    phi_: np.ndarray
    sigma_: np.ndarray
    long_run_: np.ndarray
    watched_: np.ndarray
    jump_limit_: np.ndarray

    @property
    def drift_alpha(self) -> float: ...

    def sensor_alarm(self, time_s: float, block: int, lost: np.ndarray, run: np.ndarray,
                     stale: np.ndarray, block_s: float) -> Alarm | None: ...  # fmt: skip


class CusumState:
    """The decisions of :meth:`~drafttwin.diagnosis.detect.FaultDetector.run`, one block at a
    time (the live twin feeds it each block as it closes; ``run`` feeds it a whole record: the
    same code decides).

    The first ``n_ref`` blocks make the baseline; after an alarm the CUSUMs restart from a new
    reference window. After :meth:`update`, ``deviation`` and ``statistic`` hold the block's
    level minus baseline and CUSUM over ``h`` (``None`` when the block was not decided)."""

    def __init__(self, detector: FittedDetector, n_ref: int, block_s: float) -> None:
        ns = len(STREAMS)
        self.det, self.n_ref, self.block_s = detector, n_ref, block_s
        self.a = stream_matrix()
        self.scale = detector.sigma_ * np.sqrt((1 - detector.phi_**2) * detector.long_run_)
        self.alpha = detector.drift_alpha
        self.up, self.down, self.prev = np.zeros(ns), np.zeros(ns), np.zeros(ns)
        self.fresh = True  # no decided block since the (re)baseline: ``prev`` is not one
        self.up_start, self.down_start = np.zeros(ns), np.zeros(ns)  # block end times
        self.reference: list[np.ndarray] = []
        self.base: np.ndarray | None = None
        self.rebase: list[np.ndarray] = []
        self.rebasing = False
        self.block = 0
        self.deviation: np.ndarray | None = None
        self.statistic: np.ndarray | None = None
        self.jump_ratio = np.zeros(ns)  # the block's |innovation| over its jump limit
        self.baseline_at_alarm: np.ndarray | None = None
        self.paused = False  # the last block was not steady running (see :meth:`update`)

    @property
    def ready(self) -> bool:
        """The baseline is set and no new reference window is being collected."""
        return self.base is not None and not self.rebasing

    def update(self, time_s: float, level: np.ndarray, lost: np.ndarray, run: np.ndarray,
               stale: np.ndarray, steady: bool = True) -> list[Alarm]:  # fmt: skip
        """One block's features (``level``: a :data:`FEATURES` row, the five levels then the
        angle lags; ``lost``, ``run``, ``stale``: the sensor rules'); the alarms it raises (a
        sensor rule and a CUSUM may both fire on one block). A block that is not ``steady``
        running (:func:`~drafttwin.diagnosis.blocks.commanded_steady`: a start, a stop, a
        speed change) is not judged, and the first steady block after it starts a new
        reference window, as at a record's start: the thresholds hold for steady running,
        and a stop can leave the drive's angles and temperatures where they were not."""
        j = self.block
        self.block += 1
        self.deviation = self.statistic = None
        if not steady:
            self.paused = True
            return []
        if self.paused:
            self.paused = False
            if self.base is None:
                self.reference = []
            else:
                self._restart()
        if self.base is None:  # the reference window: no decisions
            self.reference.append(level)
            if len(self.reference) == self.n_ref:
                self.base = np.nanmean(self.reference, axis=0)
            return []
        out = []
        sensor = self.det.sensor_alarm(time_s, j, lost, run, stale, self.block_s)
        if sensor is not None:
            out.append(sensor)
            self.baseline_at_alarm = self.base.copy()
            if sensor.test.startswith("stuck_"):
                # held values moved the channel's counted angle (and lag) for good: decide
                # again on a new reference window once it counts again (lost rows are
                # bridged, so a dropout needs none)
                self._restart()
                return out
        if not np.isfinite(level).all():
            return out
        if self.rebasing:  # after an alarm: a new reference window, no decisions
            self.rebase.append(level)
            if len(self.rebase) >= self.n_ref:
                self.base, self.rebasing = np.mean(self.rebase, axis=0), False
            return out
        alarm = self._cusum(time_s, j, level)
        if alarm is not None:
            out.append(alarm)
        return out

    def _raise(self, alarm: Alarm) -> Alarm:
        assert self.base is not None
        self.baseline_at_alarm = self.base.copy()
        self._restart()
        return alarm

    def _restart(self) -> None:
        """Restart like a record's start: CUSUMs at zero, the mean of the next reference
        window as the baseline (one block alone is too noisy a baseline: it set off a
        cascade of alarms)."""
        self.up[:], self.down[:], self.prev[:] = 0.0, 0.0, 0.0
        self.fresh = True
        self.rebase, self.rebasing = [], True

    def _cusum(self, time_s: float, j: int, level: np.ndarray) -> Alarm | None:
        assert self.base is not None
        det = self.det
        self.deviation = level - self.base
        s = self.deviation @ self.a.T
        e = np.where(det.watched_, (s - det.phi_ * self.prev) / self.scale, 0.0)
        jump = e * np.sqrt(det.long_run_)  # the innovation in its own (unwidened) unit
        self.prev = s
        # the first block after a (re)baseline has no block before it: its "innovation" is
        # its whole deviation, so the jump rule waits a block
        ok = (det.jump_limit_ > 0) & (not self.fresh)
        self.fresh = False
        self.jump_ratio = np.where(ok, np.abs(jump) / np.where(ok, det.jump_limit_, 1.0), 0.0)
        over = np.flatnonzero(self.jump_ratio > 1.0)
        if over.size:  # a one-block jump of an angle lag (a worn mesh steps it at once)
            i = int(over[np.argmax(self.jump_ratio[over])])
            self.statistic = np.maximum(self.up, self.down) / det.h_
            return self._raise(Alarm(time_s, j, STREAMS[i], 1 if jump[i] > 0 else -1,
                                     time_s - self.block_s, "jump"))  # fmt: skip
        for arr, start, sign in ((self.up, self.up_start, 1.0),
                                 (self.down, self.down_start, -1.0)):  # fmt: skip
            was_zero = arr <= 0
            arr[:] = np.maximum(0.0, arr + sign * e - det.k)
            start[was_zero & (arr > 0)] = time_s
        stat = self.statistic = np.maximum(self.up, self.down) / det.h_
        hit = np.flatnonzero(stat >= 1.0)
        if hit.size:
            i = int(hit[np.argmax(stat[hit])])
            side = 1 if self.up[i] >= self.down[i] else -1
            begin = (self.up_start if side > 0 else self.down_start)[i]
            return self._raise(Alarm(time_s, j, STREAMS[i], side, float(begin - self.block_s)))
        if stat.max() < 0.5:  # nothing suspicious: follow slow normal drift
            self.base = self.base + self.alpha * (level - self.base)
        return None
