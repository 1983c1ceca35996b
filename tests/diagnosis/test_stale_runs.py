"""A stuck encoder against a counting one that repeats a count (issue 39, item 4's blocker):
a counting encoder's identical counts add up to its roller's angle, so however long the run
the angle lag stays put; a held value walks the lag by the count's fractional part per
sample; a wrong gain walks it before the run as during it. Only the held value's run is
stale, and the stuck rule judges a run by that, not by its length against other machines'."""

import numpy as np
import pytest

from drafttwin.diagnosis.blocks import STALE_EDGES
from drafttwin.diagnosis.residuals import block_features
from drafttwin.plant.config import Sensors
from drafttwin.plant.sensors import encoder_rpm

EDGE_RPM = 0.6  # 10 000 edges per revolution counted over 10 ms
# second roller: 724.43 edges per sample (a held value walks 0.43-0.57 edges a sample); back
# roller: 592.01 edges per sample (its counts repeat for about 100 samples at a time)
RPM = np.array([1815.65, 434.66, 426.12, 592.01 * EDGE_RPM, 1450.0])
ROWS = 6000


def counted(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(ROWS) * 0.01
    true = RPM[None, :] * (1 + 2e-6 * np.sin(2 * np.pi * t / 37.0))[:, None]
    return encoder_rpm(true, 0.01, Sensors(clock_jitter_s=0.0), rng), true


def features(y: np.ndarray, true: np.ndarray):
    return block_features(y, true, np.arange(ROWS) * 0.01, 1.0)


def test_a_long_healthy_run_is_not_stale_a_held_value_is():
    y, true = counted(1)
    f = features(y, true)
    assert f.run[:, 3].max() >= 60  # the back encoder repeats one count for most of a block
    assert (f.stale_runs[:, :4] == 1).all()  # ... and moves no lag: no roller's run is stale
    held = y.copy()
    held[3020:3090, 1] = held[3019, 1]  # the second roller's encoder freezes for 0.7 s
    g = features(held, true)
    assert g.run[30, 1] >= 71 and g.stale_runs[30, 1] == g.run[30, 1]  # its lag walked ~35 edges
    others = np.delete(np.arange(60), 30)
    assert (g.stale_runs[others, :4] == 1).all()  # the other blocks and rollers: none


def test_a_wrong_gain_walks_the_lag_before_the_run_too():
    y, true = counted(2)
    gained = y.copy()
    gained[3000:, 1] *= 1.004  # 0.4 %: the lag walks 2.9 edges a sample, not a stale value
    g = features(gained, true)
    assert (g.stale_runs[32:, 1] == 1).all()
    assert 0.004 * RPM[1] / EDGE_RPM * 3 > STALE_EDGES  # it moved past the limit in 3 rows


def test_a_lagged_rollers_long_run_that_leaves_its_lag_put_is_not_stuck():
    """The still rule (any run past STILL_FACTOR x the run limit) judges the front roller and
    the motor only: a slower roller's run that leaves its lag put is a right reading however
    long (live, after a belt wear slowed a machine, the second roller's count sat on a whole
    number for 62 samples at a time against a run limit of 15, and was called stuck)."""
    from drafttwin.diagnosis.detect import STILL_FACTOR, FaultDetector

    y, true = counted(1)
    f = features(y, true)
    det = FaultDetector()
    det.run_limit_ = det.stale_limit_ = np.full(5, 10.0)
    det.lost_limit_ = np.full(5, 0.02)
    long_runs = np.flatnonzero(f.run[:, 3] > STILL_FACTOR * 10.0)
    assert long_runs.size > 10  # the back encoder's counting runs, past the still limit
    for b in long_runs:
        assert det.sensor_alarm(float(b), int(b), f.lost[b], f.run[b], f.stale_runs[b], 1.0) is None
    front = np.array([STILL_FACTOR * 10.0 + 1, 1, 1, 1, 1])
    a = det.sensor_alarm(0.0, 0, np.zeros(5), front, np.ones(5), 1.0)
    assert a is not None and a.test == "stuck_front"


@pytest.mark.slow
def test_a_detector_tuned_on_other_machines_names_a_stuck_encoder():
    """Each gear's own run-out: tuning machine 201's back encoder repeats one count for 78
    samples in 60 s, so a limit of twice the longest run (156) never sees a held value within
    a block; its run moves the lag, and the rule names it (was: rear_chain:elongation)."""
    from drafttwin.diagnosis.detect import FaultDetector
    from drafttwin.diagnosis.diagnose import Diagnoser
    from drafttwin.diagnosis.residuals import record_features
    from drafttwin.mechanics import DriveTrain
    from drafttwin.plant import Machine, Plant
    from drafttwin.plant.config import Eccentricity, PlantConfig
    from drafttwin.plant.faults import FaultSpec

    # the records the figures above were measured on (the plant placed at its operating
    # point, its start before 2026-12-01)
    cfg = PlantConfig(eccentricity=Eccentricity(gear_runout_law="rayleigh"),
                      start="operating-point")  # fmt: skip
    plant, train = Plant(config=cfg), DriveTrain.preset("fa320a")
    tuning = [record_features(train, plant.run(60.0, 100.0, seed=100 + k, machine=Machine.draw(
        plant.train, cfg, 200 + k)).series) for k in range(2)]  # fmt: skip
    det = FaultDetector().fit(tuning)
    assert det.run_limit_[3] >= 150 and det.stale_limit_[3] < 100
    stuck = FaultSpec.parse("back:stuck:severity=2:onset=16")
    rec = plant.run(36.0, 100.0, seed=302, faults=[stuck], machine=Machine.draw(plant.train,
                                                                                cfg, 402))  # fmt: skip
    d = Diagnoser(train, det).diagnose(rec.series)
    assert d.alarm is not None and d.alarm.test == "stuck_back" and 16 < d.alarm.time_s <= 18
    assert d.causes[0].name == "back:stuck"
