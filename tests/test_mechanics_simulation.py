"""Simulation physics: steady state, convergence, reference integrator, power, spectra."""

import math

import numpy as np
import pytest

from drafttwin import ROLLERS
from drafttwin.mechanics import (
    DriveTrain,
    Signal,
    kinematics,
    operating_point,
    simulate,
)
from drafttwin.mechanics.assembly import gear_base_radii_m
from drafttwin.mechanics.simulation import reference_node_rpm

from ._trains import FA320A, fa320a_dict, two_inertia_gear


@pytest.fixture(scope="module")
def steady():
    return simulate(FA320A, duration_s=2.0, output_rate_hz=1000.0, settle_s=1.0)


def test_steady_mean_speeds_equal_kinematics_corrected_for_slip_and_creep(steady):
    kin = kinematics(FA320A)
    op = operating_point(FA320A)
    (creep,) = op.belt_creep.values()
    correction = op.motor_rpm / kin.motor_rpm * (1 - creep)
    mean = steady.roller_rpm().mean(axis=0)
    for j, r in enumerate(ROLLERS):
        assert mean[j] == pytest.approx(kin.rollers[r].rpm * correction, rel=5e-4)
        assert mean[j] == pytest.approx(op.roller_rpm[r], rel=5e-5)


def test_fluctuations_exist_but_are_small(steady):
    rpm = steady.roller_rpm()
    rel_std = rpm.std(axis=0) / rpm.mean(axis=0)
    assert np.all(rel_std > 1e-5)  # the train is not rigid: chain and meshes excite it
    assert np.all(rel_std < 5e-3)  # and well below the paper's 0.8 % error scale


def test_power_balance(steady):
    p = steady.mean_power_w()
    losses = p["roller_loads"] + p["bearings"] + p["coupling_losses"]
    assert p["motor"] + p["external"] == pytest.approx(losses, rel=1e-2)
    assert p["roller_loads"] > 0.8 * p["motor"]  # the rollers are the main load


def test_halving_dt_changes_interval_means_below_1e5():
    a = simulate(FA320A, 1.0, settle_s=0.5, dt_s=FA320A.spec.solver.dt_s).roller_rpm()
    b = simulate(FA320A, 1.0, settle_s=0.5, dt_s=FA320A.spec.solver.dt_s / 2).roller_rpm()
    assert np.max(np.abs(a - b) / b) < 1e-5


def test_rk4_agrees_with_scipy_reference():
    rk4 = simulate(FA320A, 0.02, settle_s=0.0, dt_s=1e-5).node_rpm
    ref = reference_node_rpm(FA320A, 0.02)
    assert np.max(np.abs(rk4 - ref) / np.abs(ref)) < 1e-6


def test_same_inputs_same_numbers():
    a = simulate(FA320A, 0.2, settle_s=0.1)
    b = simulate(FA320A, 0.2, settle_s=0.1)
    np.testing.assert_array_equal(a.node_rpm, b.node_rpm)


def _amplitude(x: np.ndarray, rate: float, f: float, tol_hz: float = 2.0) -> float:
    """Peak amplitude of the line near ``f`` (Hann window, coherent-gain corrected)."""
    x = x - x.mean()
    win = np.hanning(len(x))
    spec = np.abs(np.fft.rfft(x * win)) * 2 / win.sum()
    freqs = np.fft.rfftfreq(len(x), 1 / rate)
    band = np.abs(freqs - f) <= tol_hz
    return float(spec[band].max())


def _fold(f: float, rate: float) -> float:
    f = f % rate
    return min(f, rate - f)


def test_spectrum_shows_chain_and_mesh_lines_folded_like_an_interval_mean():
    """A 20 kHz run resolves the lines; the 1 kHz interval means fold them, sinc-attenuated."""
    fine_rate, rate = 20000.0, 1000.0
    fine = simulate(FA320A, 1.0, output_rate_hz=fine_rate, settle_s=1.0)
    back = fine.node_rpm[:, fine.rollers["back"]]
    coarse = back.reshape(-1, int(fine_rate / rate)).mean(axis=1)  # 1 kHz interval means
    point = fine.point_rpm[int(fine_rate / rate) - 1 :: int(fine_rate / rate), fine.rollers["back"]]
    op = operating_point(FA320A)
    main_hz = op.node_speed_rad_s[FA320A.node_index("main_shaft")] / (2 * math.pi)
    chain_hz = 25 * main_hz
    true_amp = _amplitude(back, fine_rate, chain_hz)
    noise = (
        np.median(np.abs(np.fft.rfft((back - back.mean()) * np.hanning(len(back)))))
        * 2
        / np.hanning(len(back)).sum()
    )
    assert true_amp > 20 * noise  # the chain line stands out of the spectrum
    folded = _fold(chain_hz, rate)
    sinc = abs(np.sinc(chain_hz / rate))
    assert _amplitude(coarse, rate, folded) == pytest.approx(true_amp * sinc, rel=0.1)
    # point samples would carry the full, unattenuated line to the folded frequency
    assert _amplitude(point, rate, folded) > 2 * _amplitude(coarse, rate, folded)
    back_hz = op.roller_rpm["back"] / 60
    mesh_gh = 20 * op.node_speed_rad_s[FA320A.node_index("rear_shaft")] / (2 * math.pi)
    assert _amplitude(back, fine_rate, mesh_gh) > 5 * noise  # G-H mesh drives the back roller
    assert back_hz < 10  # once-per-revolution is far below any line tested here


def test_two_inertia_free_vibration_frequency():
    """A torque step on the load excites the mesh mode; its frequency matches the closed form."""
    j1, j2, k = 0.01, 0.002, 2.0e8
    raw = two_inertia_gear(j1, j2, k)
    train = DriveTrain.from_dict(raw).with_torque("b", Signal(0.0, 1e-6, np.array([0.0, -2.0])))
    res = simulate(train, 0.05, settle_s=0.0)
    rb1, rb2 = gear_base_radii_m(train.spec.gear[0])
    f_expected = math.sqrt(k * (rb1**2 / j1 + rb2**2 / j2)) / (2 * math.pi)
    x = res.node_rpm[:, 1] - res.node_rpm[:, 0] * 30 / 20
    x = x - x.mean()
    spec = np.abs(np.fft.rfft(x * np.hanning(len(x)), n=16 * len(x)))
    freqs = np.fft.rfftfreq(16 * len(x), 1 / 20000.0)
    assert freqs[np.argmax(spec)] == pytest.approx(f_expected, rel=0.01)


def test_supply_schedule_changes_speed_proportionally():
    train = FA320A.with_supply_schedule(Signal(0.0, 0.1, np.array([48.47, 48.47 * 0.9])))
    res = simulate(train, 1.0, output_rate_hz=100.0, settle_s=0.5)
    op_end = operating_point(train, t=1.0)
    front = res.roller_rpm()[-10:, 0].mean()
    assert front == pytest.approx(op_end.roller_rpm["front"], rel=2e-3)
    assert front == pytest.approx(0.9 * operating_point(FA320A).roller_rpm["front"], rel=3e-3)


def test_config_round_trip_gives_same_simulation():
    again = DriveTrain.from_dict(fa320a_dict())
    a = simulate(FA320A, 0.05, settle_s=0.0).node_rpm
    b = simulate(again, 0.05, settle_s=0.0).node_rpm
    np.testing.assert_array_equal(a, b)


def test_backlash_free_flight_time():
    """Reverse the load torque: the driven gear crosses the whole backlash 2b in free flight.

    With flanks apart, the relative displacement along the line of action accelerates at
    a = r_b2 * T / J2 (the driver holds its speed), so 2b is crossed after sqrt(2 * 2b / a).
    """
    raw = two_inertia_gear(j1=10.0, j2=0.002, k=2.0e8)
    raw["gear"][0]["backlash_um"] = 100.0
    raw["bearing"] = []
    torque = 5.0
    train = DriveTrain.from_dict(raw).with_torque(
        "b", Signal(0.0, 1e-3, np.array([torque, torque]))
    )
    res = simulate(train, 0.004, settle_s=0.0)
    rb1, rb2 = gear_base_radii_m(train.spec.gear[0])
    rel = np.cumsum(res.node_rpm[:, 1] * rb2 - res.node_rpm[:, 0] * rb1) * (math.pi / 30) / 20000.0
    accel = rb2 * torque / 0.002
    t_cross = math.sqrt(2 * 100e-6 / accel)
    # the initial state is loaded forward (delta = +b + static); the gap opens once the torque acts
    hit = np.argmax(np.abs(rel) >= 100e-6 + 1e-7) / 20000.0
    assert hit == pytest.approx(t_cross, rel=0.05)


def test_backlash_rattle_statistics_converge_under_dt_halving():
    """With the real 80 um backlash the change gears rattle (chaotic samples), but means agree."""
    raw = fa320a_dict()
    for g in raw["gear"]:
        g["backlash_um"] = 80.0
    train = DriveTrain.from_dict(raw)
    a = simulate(train, 1.0, settle_s=0.5).roller_rpm()
    b = simulate(train, 1.0, settle_s=0.5, dt_s=train.spec.solver.dt_s / 2).roller_rpm()
    np.testing.assert_allclose(a.mean(axis=0), b.mean(axis=0), rtol=1e-6)
    np.testing.assert_allclose(a.std(axis=0), b.std(axis=0), rtol=0.05)


def _carriage(mass=95.0, viscous=200.0):
    """A translational mass as one inertia (radius 1 m: kg for kg m^2, N for N m), no motor."""
    return {
        "inertia": [{"name": "carriage", "inertia_kgm2": mass}],
        "bearing": [{"node": "carriage", "coulomb_torque_nm": 0.0, "viscous_nms": viscous}],
        "solver": {"dt_s": 1e-4, "output_rate_hz": 1000.0, "settle_s": 0.0},
    }


def test_mass_with_viscous_friction_under_constant_force_matches_closed_form():
    mass, viscous, force = 95.0, 200.0, 100.0
    train = DriveTrain.from_dict(_carriage(mass, viscous))
    train = train.with_torque("carriage", Signal(0.0, 1.0, np.array([force, force])))
    res = simulate(train, 1.0)
    # interval mean of v(t) = F/c (1 - exp(-c t / M)) over [t - T, t], from its integral
    t = res.time_s
    tau = mass / viscous

    def x(s):
        return force / viscous * (s + tau * np.exp(-s / tau) - tau)

    expected = (x(t) - x(t - 1e-3)) / 1e-3
    np.testing.assert_allclose(res.node_rpm[:, 0] * math.pi / 30, expected, rtol=1e-9, atol=1e-12)


def test_zero_order_hold_signal_holds_each_value():
    train = DriveTrain.from_dict(_carriage(1.0, 0.0))
    steps = np.array([0.0, 1.0, 0.0, 1.0])  # N, held 10 ms each
    zoh = train.with_torque("carriage", Signal(0.0, 0.01, steps, hold="zoh"))
    lin = train.with_torque("carriage", Signal(0.0, 0.01, steps))
    v_zoh = simulate(zoh, 0.03).node_rpm[:, 0] * math.pi / 30
    v_lin = simulate(lin, 0.03).node_rpm[:, 0] * math.pi / 30
    # held: 0 N in [0, 10 ms), 1 N in [10, 20 ms), 0 N in [20, 30 ms); the step at 10 ms is
    # seen only by the last RK4 stage of the 10th interval (dt/6 * 1 N / 1 kg)
    assert v_zoh[:9].max() == pytest.approx(0.0, abs=1e-12)
    assert v_lin[:10].max() > 0  # linear interpolation ramps up at once
    assert v_zoh[29] == pytest.approx(0.01, rel=1e-2)  # after 1 N for 10 ms: 0.01 m/s
    assert np.ptp(v_zoh[21:30]) < 1e-12  # no force in the third interval: constant speed


def test_train_without_motor_has_no_operating_point():
    train = DriveTrain.from_dict(_carriage())
    with pytest.raises(Exception, match="no torque-balance operating point"):
        operating_point(train)


def test_drafting_zone_draws_force_times_speed_difference(steady):
    """The zones' power is F (v_delivering - v_feeding) from the simulated surface speeds:
    what the roller-load power gains over the same train without zones."""
    raw = fa320a_dict()
    zones = raw.pop("drafting_zone")
    bare = simulate(DriveTrain.from_dict(raw), duration_s=2.0, output_rate_hz=1000.0, settle_s=1.0)
    rollers = {r["name"]: r for r in raw["roller"]}
    surface = {r: steady.roller_rpm((r,)).mean() * math.pi / 30 * rollers[r]["diameter_mm"] / 2000
               for r in ROLLERS}  # fmt: skip
    want = sum(z["force_n"] * (surface[z["delivering"]] - surface[z["feeding"]]) for z in zones)
    # friction power is Coulomb (torque x speed): the lighter bare train runs a little faster
    faster = bare.roller_rpm().mean(axis=0) / steady.roller_rpm().mean(axis=0)
    assert np.ptp(faster) < 1e-5 and faster[0] > 1.0
    got = steady.mean_power_w()["roller_loads"] - bare.mean_power_w()["roller_loads"] / faster[0]
    assert want > 5.0  # tens of watts: the FA320A's sliver load
    assert got == pytest.approx(want, rel=1e-4), (got, want)
    assert bare.mean_power_w()["motor"] < steady.mean_power_w()["motor"]
