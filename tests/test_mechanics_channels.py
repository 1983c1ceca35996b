"""Measured channels in a drive-train declaration: [[input]] and [[output]] tables, their
defaults, units, refusals, closed-form responses and the tutorial's belt drive."""

import copy
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drafttwin import ROLLERS
from drafttwin.errors import ConfigError, DataError
from drafttwin.mechanics import (
    DriveTrain,
    OutputMap,
    Signal,
    kinematics,
    operating_point,
    simulate,
)

from ._trains import FA320A, fa320a_dict

BELT_DRIVE = Path(__file__).resolve().parents[1] / "docs" / "examples" / "belt_drive.toml"
STEP = 0.01  # s, a 100 Hz grid


def _wheel(hold: str, j: float = 0.02, c: float = 0.1, k: float = 0.5) -> dict[str, Any]:
    """A motor-less single inertia J with viscous bearing c, driven by a torque k * u."""
    return {
        "inertia": [{"name": "wheel", "inertia_kgm2": j}],
        "bearing": [{"node": "wheel", "viscous_nms": c}],
        "input": [{"channel": "u", "drives": "torque", "node": "wheel", "gain": k,
                   "hold": hold}],
        "output": [{"channel": "y", "node": "wheel", "unit": "rad/s"}],
        "solver": {"dt_s": 1e-4, "output_rate_hz": 100.0, "settle_s": 1.0},
    }  # fmt: skip


def _first_order_means(u: np.ndarray, hold: str, j: float, c: float, k: float) -> np.ndarray:
    """Interval means of J dw/dt = k u(t) - c w from rest, in closed form.

    Row 0 is the interval before the first sample (u held at u[0]); row i covers
    (t[i-1], t[i]] with u ramping from u[i-1] to u[i] (linear) or held at u[i-1] (zoh). On an
    interval with u = a + b s: w(s) = g u(s) - g tau b + C exp(-s/tau), g = k/c, tau = J/c.
    """
    g, tau = k / c, j / c
    decay = math.exp(-STEP / tau)
    starts = np.concatenate([[u[0]], u[:-1]])
    ends = np.concatenate([[u[0]], u[1:]]) if hold == "linear" else starts
    w, out = 0.0, []
    for a, e in zip(starts, ends, strict=True):
        slope = (e - a) / STEP
        const = w - g * a + g * tau * slope
        angle = g * (a + e) / 2 * STEP - g * tau * slope * STEP + const * tau * (1 - decay)
        out.append(angle / STEP)
        w = g * e - g * tau * slope + const * decay
    return np.array(out)


def _refused(raw: dict[str, Any], *parts: str) -> str:
    with pytest.raises(ConfigError) as info:
        DriveTrain.from_dict(raw, source="train.toml")
    msg = info.value.message
    assert "train.toml" in msg and "fix:" in msg
    for part in parts:
        assert part in msg
    return msg


# ---- defaults and units ----------------------------------------------------------------------
def test_default_channels_of_the_preset():
    (supply,) = FA320A.input_channels()
    assert (supply.channel, supply.drives, supply.gain, supply.offset) == (
        "supply_hz", "supply_hz", 1.0, 0.0)  # fmt: skip
    outputs = FA320A.output_channels()
    names = [o.channel for o in outputs]
    assert names[:5] == [*ROLLERS, "motor"]  # rollers by roller name; motor node is "motor"
    assert set(FA320A.node_names) <= set(names) and len(names) == len(set(names))
    assert all(o.unit == "rpm" for o in outputs)
    front = outputs[0]
    assert front == OutputMap("front", "front_roller", "rpm", 45.0)


def test_default_motor_channel_when_the_motor_node_has_another_name():
    raw = _wheel("zoh")
    raw["inertia"][0]["name"] = "rotor"
    raw["bearing"][0]["node"] = "rotor"
    raw["motor"] = {"node": "rotor", "rated_power_w": 750, "rated_rpm": 1400, "poles": 4}
    del raw["input"], raw["output"]
    train = DriveTrain.from_dict(raw)
    assert [(o.channel, o.node) for o in train.output_channels()] == [
        ("rotor", "rotor"), ("motor", "rotor")]  # fmt: skip
    assert [i.channel for i in train.input_channels()] == ["supply_hz"]
    raw.pop("motor")
    assert DriveTrain.from_dict(raw).input_channels() == ()  # no motor: no default input


def test_unit_conversions_are_exact():
    time_s = np.arange(1, 21) * STEP
    rpm = simulate(FA320A, time_s=time_s).channels(["front", "front", "motor"])
    converted = simulate(FA320A, time_s=time_s).channels(
        ["front", "second", "motor"], {"front": "rad/s", "second": "m/min", "motor": "rev/s"}
    )
    second = simulate(FA320A, time_s=time_s).channels(["second"])[:, 0]
    np.testing.assert_allclose(converted[:, 0], rpm[:, 0] * math.pi / 30, rtol=1e-15)
    np.testing.assert_allclose(converted[:, 1], second * math.pi * 0.035, rtol=1e-15)
    np.testing.assert_allclose(converted[:, 2], rpm[:, 2] / 60, rtol=1e-15)
    # declared in the file: the front roller's surface speed is the delivery speed
    raw = fa320a_dict()
    raw["output"] = [{"channel": "delivery", "node": "front", "unit": "m/min"},
                     {"channel": "body", "node": "front_roller", "unit": "m/min"}]  # fmt: skip
    train = DriveTrain.from_dict(raw)
    both = simulate(train, time_s=time_s).channels()
    np.testing.assert_allclose(both[:, 0], rpm[:, 0] * math.pi * 0.045, rtol=1e-15)
    np.testing.assert_array_equal(both[:, 0], both[:, 1])  # roller name or its node
    assert both[:, 0].mean() == pytest.approx(kinematics(FA320A).delivery_speed_m_min, rel=4e-3)


# ---- closed-form responses -------------------------------------------------------------------
@pytest.mark.parametrize("hold", ["zoh", "linear"])
def test_single_inertia_torque_input_matches_first_order_closed_form(hold):
    j, c, k = 0.02, 0.1, 0.5
    rng = np.random.default_rng(5)
    u = np.repeat(rng.uniform(-10.0, 10.0, 20), 10)  # V, a new level every 0.1 s
    u[40:60] = np.linspace(-4.0, 6.0, 20)  # and a ramp
    time_s = 123.4 + STEP * np.arange(1, len(u) + 1)  # a grid that starts anywhere
    train = DriveTrain.from_dict(_wheel(hold, j, c, k))
    got = simulate(train, time_s=time_s, inputs={"u": u}).channels()[:, 0]
    want = _first_order_means(u, hold, j, c, k)
    if hold == "linear":
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)
    else:
        # the kernel reads a held input at each RK4 stage's time, so the last stage of the step
        # ending on sample instant j already sees sample j: the speed gets a kick
        # dt/6 * k * (u[j] - u[j-1]) / J there, which then decays with tau = J/c (the
        # convention the EMPS test pins down). Its effect on the interval means, exactly:
        dt, tau = 1e-4, j / c
        kicks = dt / 6 * k / j * np.diff(u, prepend=u[0])
        rows = np.arange(len(u))
        lag = rows[:, None] - rows[None, :]  # interval i, kick at the end of interval j
        share = tau / STEP * (np.exp(-(lag - 1) * STEP / tau) - np.exp(-lag * STEP / tau))
        predicted = (np.where(lag >= 1, share, 0.0) * kicks[None, :]).sum(axis=1)
        np.testing.assert_allclose(got, want + predicted, rtol=1e-9, atol=1e-9)
        assert np.max(np.abs(predicted)) > 1e-3  # the convention is real, far above 1e-9
    # from rest, not settled: the first interval's mean is below the frictionless k u t / 2J
    # by about STEP / (3 tau) = 1.7 %
    frictionless = k * u[0] / j * STEP / 2
    assert 0.97 < got[0] / frictionless < 1.0


def test_channel_gain_and_offset_scale_the_input():
    raw = _wheel("zoh")
    raw["input"][0].update(gain=0.25, offset=1.5)  # N m = 0.25 u + 1.5
    u = np.full(100, 4.0)
    res = simulate(DriveTrain.from_dict(raw), time_s=STEP * np.arange(1, 101), inputs={"u": u})
    got = res.channels()
    np.testing.assert_allclose(got[:, 0], _first_order_means(u * 0.25 + 1.5, "zoh", 0.02, 0.1, 1.0),
                               rtol=1e-9)  # fmt: skip


# ---- the tutorial's belt drive ---------------------------------------------------------------
@pytest.fixture(scope="module")
def belt() -> DriveTrain:
    return DriveTrain.from_toml(BELT_DRIVE)


def test_belt_drive_example_kinematics_and_mapping(belt):
    raw = belt.to_dict()  # plain data without None, so it could be written back as TOML
    assert raw["input"] == [{"channel": "u", "drives": "supply_hz", "gain": 5.0, "offset": 0.0,
                             "hold": "zoh"}]  # fmt: skip
    assert DriveTrain.from_dict(raw).spec == belt.spec
    (u,) = belt.input_channels()
    assert (u.channel, u.drives, u.gain, u.offset, u.hold) == ("u", "supply_hz", 5.0, 0.0, "zoh")
    assert belt.output_channels() == (OutputMap("y", "flywheel", "rad/s", None),)
    kin = kinematics(belt, motor_rpm=1500.0)
    assert kin.node_rpm["flywheel"] == pytest.approx(750.0, rel=1e-12)  # 90/180 mm pulleys
    (mode_hz,) = kin.eigenfrequencies_hz  # the belt mode, within domain.md's 10-50+ Hz band
    assert 30.0 < mode_hz < 100.0
    op = operating_point(belt)  # 50 Hz, 2 N m load (0.2 rated at the motor)
    assert 0.0 < op.slip < 1 - 1400 / 1500  # light load: below the rated slip
    assert 0.005 < op.motor_torque_nm / (750 / (1400 * math.pi / 30)) < 0.3
    (creep,) = op.belt_creep.values()
    assert 0.0 < creep < 0.01  # ISO 5292: 0.5-1 % at rated pull, less at 20 % load


def test_belt_drive_follows_a_step_in_u(belt):
    time_s = STEP * np.arange(1, 401)
    u = np.where(time_s < 1.0, 5.0, 8.0)  # V: 25 Hz, then 40 Hz
    y = simulate(belt, time_s=time_s, inputs={"u": u}).channels()[:, 0]
    ratio = 90.0 / 180.0
    for hz, value in ((25.0, y[90]), (40.0, y[-1])):
        w_sync = 2 * math.pi * hz / 2  # 4 poles
        rated_slip_speed = (1 - 1400 / 1500) * 2 * math.pi * 50 / 2  # V/f: constant in rad/s
        assert ratio * (w_sync - rated_slip_speed) < value < ratio * w_sync
        steady = operating_point(belt.with_supply_schedule(Signal(0.0, 1.0, np.array([hz, hz]))))
        assert value == pytest.approx(steady.node_speed_rad_s[1], rel=1e-4)
    np.testing.assert_allclose(y[:99], y[0], rtol=1e-9)  # starts at the 25 Hz operating point
    assert np.all(np.diff(y[99:150]) >= -1e-9)  # then rises to the new speed
    assert y[130] - y[98] > 0.9 * (y[-1] - y[98])  # within 0.3 s (flywheel reflected: 0.025)


# ---- refusals --------------------------------------------------------------------------------
def test_refusals_of_input_tables():
    raw = _wheel("zoh")
    bad = copy.deepcopy(raw)
    bad["input"][0]["node"] = "wheeel"
    _refused(bad, "input 'u'", "'node'", "unknown node 'wheeel'", "wheel")
    bad = copy.deepcopy(raw)
    del bad["input"][0]["node"]
    _refused(bad, "input 'u'", "'node' is missing", "add node")
    bad = copy.deepcopy(raw)
    bad["input"][0].update(drives="supply_hz", node=None)
    _refused(bad, "input 'u'", "no [motor]")
    bad = copy.deepcopy(raw)
    bad["input"][0]["drives"] = "speed"
    _refused(bad, "input 'u'", "'drives'", "'speed'", "'supply_hz' or 'torque'")
    bad = copy.deepcopy(raw)
    bad["input"][0]["hold"] = "cubic"
    _refused(bad, "input 'u'", "'hold'", "'linear' or 'zoh'")
    bad = copy.deepcopy(raw)
    bad["input"][0]["gain"] = 0.0
    _refused(bad, "input 'u'", "'gain' is 0")
    bad = copy.deepcopy(raw)
    bad["input"][0]["gian"] = 2.0
    _refused(bad, "input 'u'", "unknown field 'gian'")
    bad = fa320a_dict()
    bad["input"] = [
        {"channel": "a", "drives": "supply_hz"},
        {"channel": "b", "drives": "supply_hz"},
    ]
    _refused(bad, "[[input]]", "2 inputs drive 'supply_hz' (a, b)")
    bad = fa320a_dict()
    bad["input"] = [{"channel": "a", "drives": "supply_hz", "node": "front_roller"}]
    _refused(bad, "input 'a'", "drives the motor on node 'motor'", "remove 'node'")


def test_refusals_of_output_tables():
    raw = _wheel("zoh")
    bad = copy.deepcopy(raw)
    bad["output"][0]["node"] = "fly"
    _refused(bad, "output 'y'", "unknown node 'fly'", "use a node (wheel)")
    bad = copy.deepcopy(raw)
    bad["output"][0]["unit"] = "Hz"
    _refused(bad, "output 'y'", "'unit' is 'Hz'", "'rpm', 'rad/s', 'rev/s' or 'm/min'")
    bad = copy.deepcopy(raw)
    bad["output"][0]["unit"] = "m/min"
    _refused(bad, "output 'y'", "'m/min' is a roller's surface speed", "node 'wheel'", "rad/s")
    bad = copy.deepcopy(raw)
    bad["output"].append({"channel": "y", "node": "wheel"})
    _refused(bad, "[[output]]", "channel 'y' is declared twice")
    bad = copy.deepcopy(raw)
    bad["output"][0]["channel"] = "u"
    _refused(bad, "output 'u'", "both as an input and as an output")
    bad = fa320a_dict()
    bad["output"] = [{"channel": "v", "node": "frnt"}]
    _refused(bad, "output 'v'", "unknown node 'frnt'", "or a roller (front, second, third, back)")


def test_refusals_when_simulating():
    time_s = STEP * np.arange(1, 11)
    wheel = DriveTrain.from_dict(_wheel("zoh"), source="wheel.toml")
    with pytest.raises(DataError, match="no input channel 'u'") as info:
        simulate(wheel, time_s=time_s, inputs={"v": np.zeros(10)}).channels()
    assert "wheel.toml" in info.value.message and "input channels given: v" in info.value.message
    with pytest.raises(DataError, match="no input channel 'u'"):
        simulate(wheel, time_s=time_s).channels()
    with pytest.raises(DataError, match="input channel 'u' has no finite value"):
        simulate(wheel, time_s=time_s, inputs={"u": np.full(10, np.nan)}).channels()
    with pytest.raises(DataError, match="'u' has 9 numeric values for 10 time stamps"):
        simulate(wheel, time_s=time_s, inputs={"u": np.zeros(9)}).channels()
    with pytest.raises(ConfigError, match="unknown output channel 'z'") as info:
        simulate(wheel, time_s=time_s, inputs={"u": np.zeros(10)}).channels(["z"])
    assert "use one of: y" in info.value.message
    with pytest.raises(ConfigError, match="unknown unit 'km/h'"):
        simulate(FA320A, time_s=time_s).channels(["front"], {"front": "km/h"})
    with pytest.raises(ConfigError, match="node 'motor' does not carry one roller"):
        simulate(FA320A, time_s=time_s).channels(["motor"], {"motor": "m/min"})
    with pytest.raises(ConfigError, match="channel 'back', which is not simulated"):
        simulate(FA320A, time_s=time_s).channels(["front"], {"back": "rad/s"})
    with pytest.raises(ConfigError, match="uniform, increasing time grid"):
        simulate(FA320A, time_s=np.array([0.01, 0.02, 0.04])).channels()


def test_a_grid_of_epoch_seconds_or_a_loggers_jitter_is_simulated():
    """Times stored as epoch seconds (float64 steps of about 2.4e-7 s at 1.7e9 s) and a
    clock's jitter within the data layer's 1 % had been refused as "not uniform" by every
    command that simulates, though the data layer read them."""
    n = 50
    local = simulate(FA320A, time_s=STEP * np.arange(1, n + 1)).channels(["front"])
    epoch = simulate(FA320A, time_s=1.7e9 + STEP * np.arange(1, n + 1)).channels(["front"])
    assert np.all(np.isfinite(epoch)) and epoch.shape == local.shape
    jitter = STEP * (np.arange(1, n + 1) + np.random.default_rng(0).uniform(-0.002, 0.002, n))
    jittered = simulate(FA320A, time_s=jitter).channels(["front"])
    np.testing.assert_allclose(jittered, local, rtol=1e-4)  # a median step 0.1 % off
    with pytest.raises(ConfigError, match=r"the step after sample 2 is 0.02 s against a median"):
        simulate(FA320A, time_s=np.array([0.01, 0.02, 0.04, 0.05, 0.06])).channels()
