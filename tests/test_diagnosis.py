"""Fault diagnosis: CUSUM thresholds, detection on residual features, sensor rules,
model-based localisation, and one end-to-end run on plant records."""

import numpy as np
import pytest

from drafttwin.diagnosis.detect import FaultDetector, siegmund_arl, threshold_for_arl
from drafttwin.diagnosis.locate import SignatureModel, rank_causes
from drafttwin.diagnosis.residuals import BlockFeatures, block_features
from drafttwin.mechanics import DriveTrain, operating_point

SIGMA = 1e-4  # relative level noise of a 1-s block (order of the plant's)


def synthetic(seed, n=600, phi=0.8, shift=None, at=None, drift=0.0):
    """AR(1) common-mode level noise plus small independent channel noise, 1-s blocks."""
    rng = np.random.default_rng(seed)
    e = rng.standard_normal(n) * SIGMA * np.sqrt(1 - phi**2)
    common = np.zeros(n)
    for i in range(1, n):
        common[i] = phi * common[i - 1] + e[i]
    level = common[:, None] * np.array([1, 1, 1, 1, 0.9]) + rng.standard_normal((n, 5)) * 1e-6
    level += drift * np.linspace(0, 1, n)[:, None]
    if shift is not None:
        level[at:] += shift
    return BlockFeatures(np.arange(1, n + 1, dtype=float), level, np.zeros((n, 5)),
                         np.full((n, 5), 3.0), 1.0)  # fmt: skip


@pytest.fixture(scope="module")
def detector():
    return FaultDetector(far_per_day=1.0).fit([synthetic(s) for s in range(4)])


def test_siegmund_threshold_gives_the_run_length_it_promises():
    k, target = 0.5, 200.0
    h = threshold_for_arl(target, k)
    assert siegmund_arl(h, k) == pytest.approx(target)
    rng = np.random.default_rng(0)
    s, length, alive = np.zeros(4000), np.zeros(4000), np.ones(4000, bool)
    for t in range(1, 5000):  # 4000 CUSUMs on i.i.d. N(0, 1) until each alarms
        s = np.where(alive, np.maximum(0.0, s + rng.standard_normal(4000) - k), s)
        hit = alive & (s > h)
        length[hit], alive = t, alive & ~hit
    assert not alive.any()
    assert length.mean() == pytest.approx(target, rel=0.1)


def test_healthy_running_and_slow_drift_raise_no_alarm(detector):
    assert detector.run(synthetic(10, n=3000), stop_at_first=False).alarms == []
    drift = synthetic(11, n=3000, drift=-8 * SIGMA)  # thermal slip: 8 sigma over 50 min
    assert detector.run(drift, stop_at_first=False).alarms == []


def test_a_step_is_detected_soon_after_it_and_not_before(detector):
    shift = np.array([-1, -1, -1, -1, -0.8]) * 3 * SIGMA  # a load fault: all rollers alike
    det = detector.run(synthetic(12, shift=shift, at=300))
    a = det.first
    assert a is not None and 300 < a.time_s <= 330
    assert a.direction == -1 and 290 <= a.change_s <= a.time_s


def test_one_encoder_off_trips_its_parity(detector):
    shift = np.zeros(5)
    shift[2] = 20 * SIGMA  # third roller's encoder reads 0.2 % high
    a = detector.run(synthetic(13, shift=shift, at=300)).first
    assert a is not None and a.test == "parity_third" and a.time_s <= 303


def test_sensor_rules_name_the_channel(detector):
    f = synthetic(14)
    f.run[400, 1] = 4 * detector.run_limit_[1]
    a = detector.run(f).first
    assert a is not None and (a.test, a.direction, a.time_s) == ("stuck_second", 0, 401.0)
    g = synthetic(15)
    g.lost[200, 4] = 0.5
    assert detector.run(g).first.test == "lost_motor"


def test_block_features_telescope_and_find_dropouts():
    rng = np.random.default_rng(1)
    t = np.arange(1, 1001) * 0.01
    yhat = np.tile([1800.0, 430.0, 420.0, 350.0, 1450.0], (1000, 1))
    y = yhat * (1 + 2e-4) + rng.standard_normal(yhat.shape) * 0.3
    y[::7, 1] = np.nan  # one channel loses every 7th sample
    y[500, 0] *= 1.3  # a spike is left out
    f = block_features(y, yhat, t, 1.0)
    assert f.level.shape == (10, 5)
    noise = 0.3 / yhat[0] / np.sqrt(100)  # i.i.d. sample noise averaged over a block
    np.testing.assert_allclose(f.level, 2e-4, atol=float(5 * noise.max()))
    assert abs(f.level[5, 0] - 2e-4) < 5 * noise[0]  # the 30 % spike did not count
    np.testing.assert_allclose(f.lost[:, 1], 1 / 7, atol=0.02)
    assert np.all(f.lost[:, [0, 2, 3, 4]] == 0)


@pytest.fixture(scope="module")
def signatures():
    return SignatureModel(DriveTrain.preset("fa320a"))


def test_signatures_follow_the_torque_balance(signatures):
    sig = signatures.signature("front_roller", "bearing_friction", 5.0)
    raw = DriveTrain.preset("fa320a").to_dict()
    for b in raw["bearing"]:
        if b["node"] == "front_roller":
            b["coulomb_torque_nm"] *= 6.0
            b["viscous_nms"] *= 6.0
    a, b = operating_point(DriveTrain.preset("fa320a")), operating_point(DriveTrain.from_dict(raw))
    assert sig[0] == pytest.approx(b.roller_rpm["front"] / a.roller_rpm["front"] - 1, rel=1e-9)
    assert np.ptp(sig[:4]) < 1e-9 * abs(sig[0]) and 0 < sig[4] / sig[0] < 1  # belt creep share
    rotor = signatures.signature("motor", "rotor_resistance", 0.2)
    assert rotor[4] == pytest.approx(rotor[0], rel=1e-4) and rotor[0] < 0
    belt = signatures.signature("main_belt", "belt_wear", 0.5)
    assert abs(belt[4]) < 1e-3 * abs(belt[0]) and belt[0] < 0  # the motor does not see it
    np.testing.assert_array_equal(signatures.signature("third", "gain", 0.01), [0, 0, 0.01, 0, 0])


def test_ranking_finds_belt_and_sensor_and_reports_bearing_groups(signatures):
    # common-mode noise (supply, drafting force) shared by all channels, as in the plant,
    # for the mean of a 30-s window
    cov = (3e-5) ** 2 * np.ones((5, 5)) + np.diag([1e-6**2] * 4 + [3e-6**2])
    belt = rank_causes(signatures, signatures.signature("main_belt", "belt_wear", 0.4), cov)
    assert belt[0].name == "main_belt:belt_wear"
    assert belt[0].interval[0] <= 0.4 <= belt[0].interval[1]
    gain = rank_causes(signatures, signatures.signature("third", "gain", -0.003), cov)
    assert gain[0].name == "third:gain" and gain[0].family == "sensor"
    assert gain[0].severity == pytest.approx(-0.003, rel=1e-3)
    bear = rank_causes(
        signatures, signatures.signature("third_roller", "bearing_friction", 20), cov
    )
    top = {bear[0].name, *bear[0].group}
    assert "third_roller:bearing_friction" in top  # found, as a member of its group:
    assert {"front_roller:bearing_friction", "second_roller:bearing_friction"} <= top
    assert not any(n.startswith("motor:") for n in top)  # motor-side faults move it 1:1


@pytest.mark.slow
def test_end_to_end_on_plant_records():
    from drafttwin.diagnosis.diagnose import Diagnoser
    from drafttwin.diagnosis.residuals import record_features
    from drafttwin.plant import Machine, Plant
    from drafttwin.plant.faults import FaultSpec

    plant, train = Plant(), DriveTrain.preset("fa320a")

    def record(i, *faults):
        m = Machine.draw(plant.train, plant.config, 50 + i)
        return plant.run(30.0, seed=60 + i, machine=m, faults=[FaultSpec.parse(f) for f in faults])

    det = FaultDetector().fit([record_features(train, record(i).series) for i in range(2)])
    dx = Diagnoser(train, det)
    found = dx.diagnose(record(3, "main_belt:belt_wear:severity=0.5:onset=18").series)
    assert found.alarm is not None and 18 < found.alarm.time_s < 25
    assert found.causes[0].name == "main_belt:belt_wear"
    sensor = dx.diagnose(record(4, "back:gain:severity=0.005:onset=18").series)
    assert sensor.causes[0].name == "back:gain"
    assert sensor.to_dict()["causes"][0]["family"] == "sensor"
