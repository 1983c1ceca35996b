"""The detector's long-run variance: slow wander that an AR(1) does not whiten widens the
CUSUM's scale, and with it the false alarms of long healthy running fall to the budget."""

import numpy as np

from drafttwin.diagnosis.cusum import STREAMS
from drafttwin.diagnosis.detect import FaultDetector
from drafttwin.diagnosis.residuals import BlockFeatures

SIGMA = 1e-4


def ar1(rng, n, phi, sd):
    e = rng.standard_normal(n) * sd * np.sqrt(1 - phi**2)
    x = np.zeros(n)
    x[0] = e[0] / np.sqrt(1 - phi**2)
    for i in range(1, n):
        x[i] = phi * x[i - 1] + e[i]
    return x


def record(seed, n, slow_sd):
    """1-s blocks: telescoping count noise (block means of counts: lag-1 correlation -0.5,
    as the plant's belt stream) plus a slow wander (minutes) of ``slow_sd``."""
    rng = np.random.default_rng(seed)
    e = rng.standard_normal(n + 1) * SIGMA / np.sqrt(2)
    common = np.diff(e) + ar1(rng, n, 0.995, slow_sd)
    level = common[:, None] * np.array([1, 1, 1, 1, 0.9]) + rng.standard_normal((n, 5)) * 1e-6
    return BlockFeatures(np.arange(1, n + 1, dtype=float), level, np.zeros((n, 5)),
                         np.full((n, 5), 3.0), 1.0)  # fmt: skip


def test_long_run_factor_sees_slow_wander_and_not_white_noise():
    i = STREAMS.index("rollers")
    plain = FaultDetector().fit([record(s, 900, 0.0) for s in range(4)])
    assert abs(plain.long_run_[i] - 1.0) < 0.3  # count noise alone: nothing to widen
    slow = FaultDetector().fit([record(s, 900, 0.5 * SIGMA) for s in range(4)])
    # the innovations of the slow part add up: 1 + 2 sum of the Bartlett-weighted
    # autocorrelations, several times the AR(1) variance here
    assert slow.long_run_[i] > 2.0
    assert (slow.long_run_ >= 1.0).all()  # never narrowed
    assert FaultDetector(long_run_blocks=0).fit([record(0, 900, 0.5 * SIGMA)]).long_run_[i] == 1.0


def test_long_run_widening_cuts_false_alarms_of_long_healthy_running():
    tuning = [record(s, 900, 0.5 * SIGMA) for s in range(4)]
    healthy = [record(10 + s, 3600, 0.5 * SIGMA) for s in range(3)]

    def alarms(det):
        return sum(len(det.run(f, stop_at_first=False).alarms) for f in healthy)

    without = alarms(FaultDetector(long_run_blocks=0).fit(tuning))
    with_it = alarms(FaultDetector().fit(tuning))
    assert with_it < without and with_it <= 1  # 3 h of running at a 1-per-24-h budget
