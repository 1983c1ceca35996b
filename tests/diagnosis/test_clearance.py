"""An alarm returns to normal when its stream is back at the baseline it left (a belt
replaced), and stays active while the fault stays (the detector's CUSUMs restart after the
alarm, so they alone cannot say it is still there)."""

from __future__ import annotations

import numpy as np

from drafttwin.diagnosis.detect import FaultDetector
from drafttwin.diagnosis.residuals import block_features
from drafttwin.diagnosis.stream import decide

from ..twin.test_twin_faults import samples


def test_a_fault_that_goes_away_returns_to_normal_and_one_that_stays_does_not() -> None:
    det = FaultDetector(reference_s=10.0).fit(
        [block_features(y, yh, t, 1.0) for t, y, yh in (samples(s, 120) for s in range(3))]
    )
    step = np.array([1, 1, 1, 1, 0]) * -8e-4  # the rollers slow, the motor does not: belt-like
    t, y, yhat = samples(21, 160, shift=step, at_s=40.0)
    stays = decide(det, block_features(y, yhat, t, 1.0))[1]
    assert stays.alarms and stays.alarms[0].test == "belt" and not stays.cleared
    # the same fault removed at 90 s: back to normal CLEAR_S later (within two blocks)
    rel = y / yhat - 1
    back = t - t[0] >= 90.0
    y[back] = yhat[back] * (1 + rel[back] - step)
    gone = decide(det, block_features(y, yhat, t, 1.0))[1]
    first = gone.alarms[0]
    assert first.test == "belt" and first.direction == -1 and gone.cleared == [first]
    # the repair is a change too, against the baseline taken after the alarm: a second belt
    # alarm, upward (after maintenance an operator has the machine learnt again instead)
    assert [(a.test, a.direction) for a in gone.alarms[1:]] == [("belt", 1)]
