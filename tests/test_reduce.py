"""The reduced drive train (stiff couplings rigid) against the full model."""

from __future__ import annotations

import numpy as np
import pytest

from drafttwin.errors import ConfigError
from drafttwin.mechanics import (
    DriveTrain,
    Signal,
    operating_point,
    reduce,
    simulate,
)
from drafttwin.mechanics import kernel as K
from drafttwin.mechanics import reduced as R
from drafttwin.mechanics.assembly import Belt

RATE = 1000.0
BLOCK = 100  # samples per 0.1 s block at 1 kHz

# start from rest with a 1.5 s VFD ramp to 48.47 Hz, hold, then a speed change to 40 Hz
SCHEDULE = Signal.from_samples([0.0, 1.5, 2.5, 3.0, 4.0], [0.0, 48.47, 48.47, 40.0, 40.0], 1e-2)


def _blocks(x: np.ndarray) -> np.ndarray:
    return x[: len(x) // BLOCK * BLOCK].reshape(-1, BLOCK, x.shape[1]).mean(axis=1)


@pytest.fixture(scope="module")
def train() -> DriveTrain:
    return DriveTrain.preset("fa320a").with_supply_schedule(SCHEDULE)


@pytest.fixture(scope="module")
def full(train):
    return simulate(train, 4.0, output_rate_hz=RATE, from_rest=True, settle_s=0.0)


def _reduced(train, dt_s=None):
    return simulate(reduce(train), 4.0, output_rate_hz=RATE, from_rest=True, settle_s=0.0,
                    dt_s=dt_s)  # fmt: skip


def test_fa320a_reduces_to_motor_and_belt_driven_block():
    red = reduce(DriveTrain.preset("fa320a")).reduction
    assert red is not None
    assert red.n_super == 2  # motor | everything behind the belt
    assert "main_belt" not in red.rigid and len(red.rigid) == 10
    assert 50.0 < red.highest_hz < 60.0  # the belt mode (54.6 Hz in the full train)
    assert 1e-3 <= red.dt_s <= 2e-3


def test_steady_speeds_equal_the_operating_point():
    # the reduced steady state is the same torque balance (Kloss slip, belt creep, friction);
    # what is left is the 0.5 % motor torque ripple at 2 f_supply (97 Hz), filtered by the
    # 10 ms lag and the inertia and averaged over 48 periods: a few 1e-9 of the speed
    train = DriveTrain.preset("fa320a")
    res = simulate(reduce(train), 1.0, output_rate_hz=RATE)
    want = operating_point(train).node_speed_rad_s * 30 / np.pi
    got = res.node_rpm[-500:].mean(axis=0)
    np.testing.assert_allclose(got, want, rtol=1e-6)


def test_startup_and_speed_change_error_against_full_model(train, full):
    # measured: RMSE of 0.1 s block means 1e-5 to 2e-5 of the steady speed per roller
    # (what the full model's mesh, chain and roller-torsion vibrations leave in a block);
    # bound 1e-4 (0.01 %), 50x below the 0.5 %
    red = _reduced(train)
    steady = full.roller_rpm()[2000:2500].mean(axis=0)
    err = _blocks(red.roller_rpm()) - _blocks(full.roller_rpm())
    rmse = np.sqrt((err**2).mean(axis=0)) / steady
    assert np.all(rmse < 1e-4), rmse
    # the speed comes from the step (timings are benchmarks/bench_reduce.py's business)
    assert red.dt_s >= 25 * full.dt_s


def test_halving_the_reduced_step_changes_much_less_than_the_error(train, full):
    coarse = _reduced(train)
    fine = _reduced(train, dt_s=coarse.dt_s / 2)
    assert fine.dt_s == pytest.approx(coarse.dt_s / 2)
    change = np.abs(_blocks(fine.roller_rpm()) - _blocks(coarse.roller_rpm())).max()
    error = np.abs(_blocks(coarse.roller_rpm()) - _blocks(full.roller_rpm())).max()
    assert change < 0.01 * error, (change, error)


def test_energy_balance(train):
    # motor work = losses + kinetic energy of the super-nodes + belt strain energy
    red_train = reduce(train)
    red = red_train.reduction
    assert red is not None
    y0 = np.zeros(2 * len(train.node_names) + 1 + 2 + 5)
    y, args = R.reduced_start(red_train, y0)
    K.integrate_reduced(y, 0.0, 1e-3, 3000, 1, args)
    m = red.n_super
    inv_jc = args[3]
    kinetic = 0.5 * float(np.sum(y[m : 2 * m] ** 2 / inv_jc))
    belt = train.spec.belt[0]
    strain = 0.5 * belt.span_stiffness_n_per_m * y[2 * m] ** 2
    motor, loads, bearings, couplings, external = y[-5:]
    residual = motor - loads - bearings - couplings + external - kinetic - strain
    assert kinetic > 100.0 and strain > 0.0
    assert abs(residual) < 1e-8 * motor, (residual, motor)


def test_cut_off_above_all_modes_gives_the_full_model():
    train = DriveTrain.preset("fa320a")
    same = reduce(train, cutoff_hz=1e5)
    assert same.reduction is not None
    assert same.reduction.rigid == () and same.reduction.n_super == len(train.node_names)
    dt = train.spec.solver.dt_s
    a = simulate(train, 0.05, output_rate_hz=RATE, settle_s=0.01, dt_s=dt)
    b = simulate(same, 0.05, output_rate_hz=RATE, settle_s=0.01, dt_s=dt)
    np.testing.assert_allclose(b.node_rpm, a.node_rpm, rtol=1e-12)
    np.testing.assert_allclose(b.energy_j, a.energy_j, rtol=1e-9)


def test_belts_stay_compliant_whatever_the_cut_off():
    red = reduce(DriveTrain.preset("fa320a"), cutoff_hz=1.0).reduction
    assert red is not None
    assert "main_belt" not in red.rigid and red.n_super == 2
    assert isinstance(DriveTrain.preset("fa320a").spec.belt[0], Belt)


def test_reduction_survives_inputs_and_channels(train):
    red_train = reduce(DriveTrain.preset("fa320a"))
    time_s = np.arange(1, 501) / RATE
    hz = np.full(time_s.shape, 48.47)
    res = simulate(red_train, time_s=time_s, inputs={"supply_hz": hz})
    y = res.channels(["front"], {"front": "m/min"})
    assert red_train.with_supply_schedule(SCHEDULE).reduction is red_train.reduction
    assert y[-1, 0] == pytest.approx(256.6, rel=2e-3)  # delivery speed, m/min


@pytest.mark.parametrize("bad", [0.0, -5.0, float("nan"), float("inf")])
def test_bad_cut_off_is_a_config_error(bad):
    with pytest.raises(ConfigError, match="cut-off"):
        reduce(DriveTrain.preset("fa320a"), cutoff_hz=bad)
