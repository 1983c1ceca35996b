"""When an alarm returns to normal: its stream back near the baseline it left.

After an alarm the CUSUMs restart from a new reference window, so the detector itself stops
seeing a persistent fault. Whether the fault is still *there* is another question, the one
an alarm list answers (an OPC UA condition's ActiveState): a machine alarm returns to normal
when the stream that raised it, averaged over the last :data:`CLEAR_S` of blocks, lies within
:data:`CLEAR_Z` of its healthy block SD around the baseline *before* the alarm (a belt
replaced, a load restored: a mean, since one healthy block in twenty lies past 2 SD); a
sensor alarm when its rule has not fired for as long. A worn mesh does not
un-wear: its lag stays off and its alarm stays active until the machine is serviced and
learnt again.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from drafttwin.diagnosis.cusum import STREAMS, Alarm, stream_matrix
from drafttwin.diagnosis.detect import FaultDetector

CLEAR_Z = 2.0
"""A mean deviation within this many of the stream's healthy block SDs counts as normal."""
CLEAR_S = 30.0
"""Seconds of blocks the deviation is averaged over (and a sensor rule must stay quiet)."""


@dataclass
class _Watched:
    alarm: Alarm
    base: np.ndarray | None  # the baseline before the alarm (features); None: a sensor rule
    normal: int = 0  # a sensor rule: consecutive blocks without it
    z: deque[float] = field(default_factory=deque)  # a stream: its last deviations, in SDs


class Clearance:
    """The active alarms of one run, each watched for its return to normal."""

    def __init__(self, detector: FaultDetector, block_s: float) -> None:
        self.detector = detector
        self.blocks = max(1, int(round(CLEAR_S / block_s)))
        self.a = stream_matrix()
        self.active: list[_Watched] = []

    def raised(self, alarm: Alarm, base: np.ndarray | None) -> None:
        """An alarm to watch (``base``: the baseline it left; ``None`` for a sensor rule)."""
        self.active.append(_Watched(alarm, None if base is None else base.copy()))

    def carried(self) -> list[tuple[Alarm, np.ndarray | None]]:
        """The alarms still watched that a new run can go on watching, each with the
        baseline it left (:func:`carries_over`)."""
        return [(w.alarm, w.base) for w in self.active if carries_over(w.alarm, w.base)]

    def block(self, features: np.ndarray, sensor_tests: set[str]) -> list[Alarm]:
        """One block's features and the sensor rules it fired; the alarms it returned to
        normal."""
        cleared = []
        for w in list(self.active):
            if w.base is None:
                w.normal = w.normal + 1 if w.alarm.test not in sensor_tests else 0
                back = w.normal >= self.blocks
            else:
                if not np.isfinite(features).all():
                    continue  # a block without a measurement says nothing
                i = STREAMS.index(w.alarm.test)
                w.z.append(float((features - w.base) @ self.a[i]) / self.detector.sigma_[i])
                if len(w.z) > self.blocks:
                    w.z.popleft()
                back = len(w.z) == self.blocks and abs(float(np.mean(w.z))) < CLEAR_Z
            if back:
                self.active.remove(w)
                cleared.append(w.alarm)
        return cleared


def carries_over(alarm: Alarm, base: np.ndarray | None) -> bool:
    """Whether another run (after a gap, or in a restarted twin) can judge ``alarm``'s return
    to normal: a sensor rule's, or a level stream's with the baseline it left (``base``;
    none kept with an alarm stored before 2026-11-30). Not an angle lag's: a lag is counted
    from its run's start, so another run's lag cannot be held against this baseline (and a
    worn mesh does not un-wear: it stays active until serviced)."""
    if alarm.direction == 0:
        return True
    return base is not None and not alarm.test.startswith("lag_")


__all__ = ["CLEAR_S", "CLEAR_Z", "Clearance", "carries_over"]
