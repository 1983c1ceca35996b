"""The angle lags keep the steps diagnosis looks for (issue 29, item 1): a lost logger row
next to a step is bridged without matching the step away, and a worn mesh's one-row lag
step on one roller is counted, not bridged as a data-path spike (which still is)."""

import numpy as np
import pytest

from drafttwin.diagnosis.residuals import angle_lag, block_features, measured, physics_prediction
from drafttwin.mechanics import DriveTrain
from drafttwin.plant.config import Sensors
from drafttwin.plant.sensors import encoder_rpm

RPM = np.array([1815.65, 434.66, 426.12, 355.10, 1450.0])  # the four rollers and the motor


def one_row_step(step_mrad: float, row: int, n: int = 1500, seed: int = 0):
    """Counted speeds at 100 Hz, the third roller falling behind by ``step_mrad`` within
    one row (a worn mesh taking up its backlash), and the steady prediction."""
    rng = np.random.default_rng(seed)
    true = np.repeat(RPM[None, :], n, axis=0)
    true[row, 2] -= step_mrad * 1e-3 / (2 * np.pi) * 60 / 0.01
    return encoder_rpm(true, 0.01, Sensors(clock_jitter_s=0.0), rng), np.repeat(RPM[None, :], n, 0)


def test_a_one_row_step_next_to_a_lost_row_is_kept_and_spikes_are_bridged():
    """9 mrad in one row is a 2 % dip of the third roller alone: the 1 % spike band bridged
    it (lag step 0), and one lost row 3 rows before it matched what was left away."""
    t = np.arange(1500) * 0.01
    y, yhat = one_row_step(9.0, 1003)
    y[1000] = np.nan  # a lost logger row 30 ms before the step
    y[600, 2] *= 1.2  # data-path spikes of one channel: bridged, the angle unmoved
    y[1300, 3] *= 0.8
    lag = block_features(y, yhat, t, 1.0).lag
    step = lag[11:].mean(axis=0) - lag[:10].mean(axis=0)
    assert step == pytest.approx([0.0, -9.0, 0.0], abs=0.7)  # an edge is 0.63 mrad


@pytest.fixture(scope="module")
def plant():
    from drafttwin.plant import Machine, Plant

    p = Plant()
    return p, lambda seed: Machine.draw(p.train, p.config, seed), DriveTrain.preset("fa320a")


def lag_steps(plant, machine_seed: int, fault: str, lose_before: int | None):
    """Measured and true lag step (mean of the blocks after the 5-s onset minus before) of
    an 8-s record; ``lose_before``: one logger row lost that many rows before the step."""
    from drafttwin.plant.faults import FaultSpec

    p, draw, train = plant
    rec = p.run(8.0, seed=3, machine=draw(machine_seed), faults=[FaultSpec.parse(fault)])
    y, yhat, t = measured(rec.series), physics_prediction(train, rec.series), rec.series.time_s
    truth = np.column_stack([rec.true_rpm, rec.true_motor_rpm])
    true_lag = angle_lag(truth, yhat, np.ones(truth.shape, bool), 0.01)
    if lose_before is not None:
        moved = np.abs(np.diff(true_lag, axis=0)).max(axis=1) > 1.0  # the step's first row
        y[int(np.argmax(moved)) + 1 - lose_before] = np.nan
    lag = block_features(y, yhat, t, 1.0).lag
    true_blocks = true_lag[:800].reshape(8, 100, 3).mean(axis=1)
    return (lag[6:].mean(axis=0) - lag[:5].mean(axis=0),
            true_blocks[6:].mean(axis=0) - true_blocks[:5].mean(axis=0))  # fmt: skip


def test_a_lost_row_before_a_chain_elongation_step_keeps_the_step(plant):
    """The issue's case: a 1.1 % chain elongation steps the third and the back roller's lag
    by about -21 / -17 mrad (their slack taken up in 20-40 ms); one lost row 30 ms before
    it left -3.7 / -2.6 and the severity 0.14 %. Without the lost row the dip (2.3 % on
    both rollers for one row) was bridged as two spikes: no step at all."""
    got, true = lag_steps(plant, 7, "rear_chain:elongation:severity=1.1:onset=5", 3)
    assert true[1:] == pytest.approx([-20.6, -17.1], abs=1.0)  # the physics of the plant
    assert got == pytest.approx(true, abs=1.5)


def test_a_one_row_wear_step_on_one_roller_is_kept(plant):
    """A severe I-J wear (250 um) steps the third roller's lag by -9 mrad in one row of
    1-1.5 % on that roller alone: the 1 % spike band bridged it and the step was lost
    (on this machine; on others the dip stays just inside the band)."""
    got, true = lag_steps(plant, 5, "I-J:wear:severity=250:onset=5", None)
    assert true == pytest.approx([0.0, -9.0, 0.0], abs=0.3)
    assert got == pytest.approx(true, abs=1.0)


@pytest.mark.long  # 2 x 300 s healthy and a 60-s fault record of the full plant: about 60 CPU-s
@pytest.mark.parametrize("machine_seed", [7, 9])
def test_diagnose_sizes_an_elongation_after_a_lost_row_within_its_interval(plant, machine_seed):
    """The issue's done-when: a 1.1 % chain elongation with a logger row lost 30 ms before
    its step is named first and its interval holds 1.1 (on machines 7 and 9 it did not
    before the lags' walk and the signature's model error entered the ranking: 1.081
    [1.067, 1.095] and 1.052 [1.011, 1.094]). The healthy records are long enough for the
    angle lags to be watched (``LAG_TUNING_BLOCKS`` decided blocks: 2 x 100 s, this test's
    records until that rule came, leave them unwatched and nothing alarms)."""
    from dataclasses import replace

    from drafttwin.diagnosis.detect import FaultDetector
    from drafttwin.diagnosis.diagnose import Diagnoser
    from drafttwin.diagnosis.residuals import record_features
    from drafttwin.plant.faults import FaultSpec

    p, draw, train = plant
    machine = draw(machine_seed)
    healthy = [record_features(train, p.run(300.0, seed=100 * machine_seed + i,
                                            machine=machine).series, 1.0) for i in (1, 2)]  # fmt: skip
    rec = p.run(60.0, seed=100 * machine_seed, machine=machine,
                faults=[FaultSpec.parse("rear_chain:elongation:severity=1.1:onset=30")])  # fmt: skip
    truth = np.column_stack([rec.true_rpm, rec.true_motor_rpm])
    true_lag = angle_lag(
        truth, physics_prediction(train, rec.series), np.ones(truth.shape, bool), 0.01
    )
    row = int(np.argmax(np.abs(np.diff(true_lag, axis=0)).max(axis=1) > 1.0)) + 1 - 3
    values, motor = rec.series.values.copy(), rec.series.motor_rpm.copy()
    values[row], motor[row] = np.nan, np.nan
    series = replace(rec.series, values=values, motor_rpm=motor)
    detector = FaultDetector().fit(healthy)
    assert detector.lags_watched, detector.lags_note()
    top = Diagnoser(train, detector).diagnose(series).causes[0]
    assert (top.element, top.kind) == ("rear_chain", "elongation")
    assert top.interval[0] <= 1.1 <= top.interval[1] and top.fits
