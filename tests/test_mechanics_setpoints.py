"""The physics follows the machine's recorded set-points: start-up, speed change, stop.

The plant runs the true machine (drawn parameters, backlash, drafting force, thermal drift,
supply jitter) through the scenario's VFD schedule and records the set-point as ``supply_hz``;
the mechanistic model gets only that column and its nominal parameters.

Measured with seed 3 (front roller, rpm): start-up, first 5 s: constant operating point
1416.1, following the set-point 0.75; speed change (-15 %), second half: 233.8 and 1.12.
Seeds 0, 1, 7, 11 give 0.56-0.81 (start-up) and 0.92-1.13 (speed change). The remaining
error is the plant's steady offset, 0.14-0.64 rpm with the model faster (drawn friction,
creep and breakdown torque, thermal slip drift; the preset has the mean drafting force).
"""

import math

import numpy as np
import pytest

from drafttwin import ROLLERS
from drafttwin.errors import ConfigError
from drafttwin.mechanics import (
    STOPPED_SUPPLY_HZ,
    Signal,
    drive_from_inputs,
    operating_point,
    simulate,
    starts_at_rest,
)
from drafttwin.plant.emulator import Plant

from ._trains import FA320A

RUNNING_FRONT_RPM = operating_point(FA320A).roller_rpm["front"]
# Bound on the RMSE of the front roller: 0.2 % of its running speed (3.6 rpm). The plant's
# documented mismatch moves the steady speed by up to about 0.1 %: slip 0.27 % scaled by the
# drawn friction (+-15 %) and breakdown torque (+-7 %), creep 0.063 % by the belt rigidity
# (+-30 %), thermal slip drift and supply jitter about 0.01 % each; doubled for transients.
RMSE_BOUND_RPM = 0.002 * RUNNING_FRONT_RPM


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2)))


@pytest.fixture(scope="module")
def startup():
    rec = Plant().run(6.0, rate_hz=100, seed=3, scenario="startup")
    sim = simulate(FA320A, time_s=rec.series.time_s, inputs=rec.series.inputs).channels(ROLLERS)
    return rec, sim


@pytest.fixture(scope="module")
def speed_change():
    rec = Plant().run(6.0, rate_hz=100, seed=3, scenario="speed-change")
    sim = simulate(FA320A, time_s=rec.series.time_s, inputs=rec.series.inputs).channels(ROLLERS)
    return rec, sim


def test_startup_is_tracked_from_rest(startup):
    rec, sim = startup
    time_s, true_front = rec.series.time_s, rec.true_rpm[:, 0]
    first5 = time_s <= 5.0
    assert rec.series.inputs["supply_hz"][0] < STOPPED_SUPPLY_HZ  # the record starts stopped
    assert np.abs(sim[0]).max() < 1e-9  # so the model starts from rest
    constant = np.full_like(true_front, RUNNING_FRONT_RPM)  # the model before: one op point
    before = _rmse(constant[first5], true_front[first5])
    after = _rmse(sim[first5, 0], true_front[first5])
    assert before > 1000.0
    assert after < RMSE_BOUND_RPM
    assert before / after > 50.0
    # every roller follows, each within the same relative bound of its running speed
    running = np.array([operating_point(FA320A).roller_rpm[r] for r in ROLLERS])
    rel = np.sqrt(np.mean((sim[first5] - rec.true_rpm[first5]) ** 2, axis=0)) / running
    assert np.all(rel < 0.002)


def test_speed_change_is_tracked(speed_change):
    rec, sim = speed_change
    time_s, true_front = rec.series.time_s, rec.true_rpm[:, 0]
    change = time_s > 3.0  # the set-point drops 15 % from half time on
    assert rec.series.inputs["supply_hz"][-1] == pytest.approx(0.85 * 48.47)
    before = _rmse(np.full(change.sum(), RUNNING_FRONT_RPM), true_front[change])
    after = _rmse(sim[change, 0], true_front[change])
    assert before > 200.0
    assert after < RMSE_BOUND_RPM
    assert before / after > 50.0
    # the record starts running: the model starts at the operating point, not from rest
    assert sim[0, 0] == pytest.approx(RUNNING_FRONT_RPM, rel=2e-3)


def test_missing_setpoint_samples_are_bridged_in_time(startup):
    rec, sim = startup
    holes = rec.series.inputs["supply_hz"].copy()
    holes[150:170] = np.nan  # on the linear ramp (1.51-1.70 s of 0.6-8.6 s)
    res = simulate(FA320A, time_s=rec.series.time_s, inputs={"supply_hz": holes})
    again = res.channels(ROLLERS)
    np.testing.assert_allclose(again, sim, rtol=1e-9, atol=1e-9)
    holes[:3], holes[-5:] = np.nan, np.nan  # at the ends: the nearest known value is held
    filled = drive_from_inputs(FA320A, rec.series.time_s, {"supply_hz": holes}).supply_hz
    assert filled is not None
    np.testing.assert_array_equal(filled.values[-5:], holes[-6])
    np.testing.assert_array_equal(filled.values[:3], holes[3])
    np.testing.assert_allclose(filled.values[150:170], rec.series.inputs["supply_hz"][150:170])


def test_stop_brakes_the_train_to_rest():
    """The supply ramps to 0 Hz: the motor (Kloss in slip speed, slip = -speed) brakes the
    train; nothing divides by the supply or the speed, so it ends at rest, finite."""
    time_s = np.arange(1, 301) * 0.01
    hz = np.interp(time_s, [0.0, 0.2, 2.2, 3.0], [48.47, 48.47, 0.0, 0.0])
    speeds = simulate(FA320A, time_s=time_s, inputs={"supply_hz": hz}).channels()
    assert np.isfinite(speeds).all()
    assert speeds[10, 0] == pytest.approx(RUNNING_FRONT_RPM, rel=2e-3)
    at_half = np.searchsorted(time_s, 1.2)  # half-way down the ramp: about half speed
    assert speeds[at_half, 0] == pytest.approx(0.5 * RUNNING_FRONT_RPM, rel=0.03)
    assert np.abs(speeds[-50:]).max() < 1e-6  # all nodes at rest for the last 0.5 s


def test_steady_preset_unchanged():
    """Without set-points: exactly the earlier grid simulation (constant supply_hz)."""
    time_s = 123.4 + np.arange(1, 51) * 0.01
    step = float(np.median(np.diff(time_s)))  # the earlier implementation, inline
    old = simulate(FA320A, duration_s=50 * step, output_rate_hz=1.0 / step,
                   t_start_s=float(time_s[0]) - step).roller_rpm()  # fmt: skip
    np.testing.assert_array_equal(simulate(FA320A, time_s=time_s).roller_rpm(), old)
    np.testing.assert_array_equal(simulate(FA320A, time_s=time_s).channels(ROLLERS), old)
    # a constant recorded set-point equal to the configured one gives the same numbers
    const = {"supply_hz": np.full(50, FA320A.spec.motor.supply_hz), "unused": np.zeros(50)}
    np.testing.assert_allclose(
        simulate(FA320A, time_s=time_s, inputs=const).channels(ROLLERS), old, rtol=1e-9
    )


def test_start_rule_threshold_and_stopped_operating_point():
    def at(hz: float):
        return FA320A.with_supply_schedule(Signal(0.0, 1.0, np.array([hz, hz])))

    assert starts_at_rest(at(0.0), 0.0) and starts_at_rest(at(0.49), 0.0)
    assert not starts_at_rest(at(0.51), 0.0) and not starts_at_rest(FA320A, 0.0)
    with pytest.raises(ConfigError, match="stopped train has no running operating point"):
        operating_point(at(0.0))
    # just above the threshold the operating point exists and runs at a crawl
    crawl = operating_point(at(0.6)).motor_rpm
    assert 0 < crawl < 60 * 0.6 / 2


def test_supply_below_zero_is_clamped():
    """A noisy analog set-point slightly below 0 V does not reverse the motor."""
    time_s = np.arange(1, 21) * 0.01
    hz = np.full(20, -0.3)
    speeds = simulate(FA320A, time_s=time_s, inputs={"supply_hz": hz}).channels(("motor",))
    np.testing.assert_array_equal(speeds, 0.0)
    assert math.isfinite(float(speeds.sum()))


def test_cli_refuses_a_negative_supply_and_notes_one_far_above_the_rated(tmp_path):
    import pandas as pd
    from typer.testing import CliRunner

    from drafttwin.cli import app

    t = np.arange(0, 1.0, 0.01)
    for hz, words in ((-48.0, "goes down to -48 Hz; a VFD's set-point is not signed"),
                      (480.0, "reaches 480 Hz, 9.9 x the motor's rated 48.47 Hz")):  # fmt: skip
        path = tmp_path / f"sp{hz:g}.csv"
        pd.DataFrame({"time": t, "supply_hz": np.full(t.shape, hz)}).to_csv(path, index=False)
        res = CliRunner().invoke(app, ["simulate", "--setpoints", str(path), "--reduced"])
        assert words in res.output and "Traceback" not in res.output, res.output
        assert res.exit_code == (2 if hz < 0 else 0), res.output


def test_a_setpoint_file_with_its_own_column_names_is_mapped_by_columns(tmp_path):
    """The refusal of a file without the input column said 'map yours: --columns volts=u',
    an option simulate did not have."""
    import pandas as pd
    from typer.testing import CliRunner

    from drafttwin.cli import app

    t = np.arange(0.01, 1.0, 0.01)
    named = tmp_path / "named.csv"
    pd.DataFrame({"time": t, "supply_hz": np.full(t.shape, 40.0)}).to_csv(named, index=False)
    other = tmp_path / "other.csv"
    pd.DataFrame({"zeit": t, "hz": np.full(t.shape, 40.0)}).to_csv(other, index=False)
    runner = CliRunner()
    res = runner.invoke(app, ["simulate", "--setpoints", str(other), "--reduced"])
    assert res.exit_code == 2 and "--columns" in res.output, res.output
    outs = []
    for path, extra in ((named, []), (other, ["--columns", "zeit=time,hz=supply_hz"])):
        out = tmp_path / f"{path.stem}.out.csv"
        res = runner.invoke(app, ["simulate", "--setpoints", str(path), "--reduced", *extra,
                                  "--out", str(out)])  # fmt: skip
        assert res.exit_code == 0, res.output
        outs.append(pd.read_csv(out))
    pd.testing.assert_frame_equal(outs[0], outs[1])  # the same run under other names
    res = runner.invoke(app, ["simulate", "--columns", "hz=supply_hz", "--duration", "0.1"])
    assert res.exit_code == 2 and "--setpoints" in res.output and "Traceback" not in res.output
