"""One RK4 loop for the full and the reduced train, one ``simulate`` for a duration or a grid."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

import drafttwin.mechanics as mechanics
from drafttwin.errors import ConfigError
from drafttwin.mechanics import DriveTrain, SimulationResult, reduce, simulate
from drafttwin.mechanics import kernel as K
from drafttwin.mechanics import reduced as R
from drafttwin.mechanics.start import _start_state

FA320A = DriveTrain.preset("fa320a")
BELT = DriveTrain.from_toml("docs/examples/belt_drive.toml")


def test_the_kernels_take_one_bundle_and_share_one_rk4_loop():
    for fn in (K.rhs, K.reduced_rhs, K._rk4, K.integrate, K.integrate_reduced):
        assert len(inspect.signature(fn.py_func).parameters) <= 8, fn
    sources = inspect.getsource(K) + inspect.getsource(R)
    assert sources.count("for stage in range(4)") == 1  # one RK4 loop for both trains


def test_a_reduction_that_keeps_every_coupling_steps_bit_for_bit_like_the_full_train():
    # every node its own super-node (ratio 1, offset 0): the reduced derivative, selected by
    # the bundle's type, must give the full one's arithmetic through the same loop
    same = reduce(FA320A, cutoff_hz=1e5)
    y_full = _start_state(FA320A, 0.0, from_rest=False)
    y_red, model = R.reduced_start(same, y_full)
    assert len(model.inv_jc) == len(FA320A.node_names)
    full = K.integrate(y_full.copy(), 0.0, 2e-5, 4, 25, FA320A.tables().kernel())
    red = K.integrate_reduced(y_red, 0.0, 2e-5, 4, 25, model)
    for a, b in zip(full, red, strict=True):
        np.testing.assert_array_equal(a, b)
    assert np.all(full[1][-1] > 10.0)  # it ran: every node turns


def test_one_public_simulate_entry():
    # a duration or a grid: simulate; the same run in pieces: simulate_chunks (the tests'
    # SciPy reference, simulate.reference_node_rpm, is not exported)
    entries = {n for n in mechanics.__all__ if n.startswith("simulate")}
    assert entries == {"simulate", "simulate_chunks"}
    assert not hasattr(mechanics, "grid")


def test_simulate_on_a_grid_returns_the_result_with_its_channels():
    time_s = 0.01 * np.arange(1, 81)
    u = np.full(len(time_s), 8.0)  # 8 V: a 40 Hz set-point
    res = simulate(BELT, time_s=time_s, inputs={"u": u})
    assert isinstance(res, SimulationResult)
    np.testing.assert_allclose(res.time_s, time_s, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(res.channels(), res.channels(["y"]))  # default: all
    # 40 Hz on a 4-pole motor through a 2:1 belt: the flywheel just under 40 pi / 2 rad/s
    assert 0.9 * 20 * np.pi < res.channels()[-1, 0] < 20 * np.pi
    fast = reduce(FA320A)
    grid = simulate(fast, time_s=time_s)
    rollers = [grid.rollers[r] for r in ("front", "second", "third", "back")]
    np.testing.assert_array_equal(grid.roller_rpm(), grid.node_rpm[:, rollers])
    assert grid.channels(["front"], {"front": "rad/s"})[-1, 0] == pytest.approx(
        grid.roller_rpm()[-1, 0] * np.pi / 30
    )


@pytest.mark.parametrize(
    "kwargs",
    [
        {},  # neither a duration nor a grid
        {"duration_s": 1.0, "time_s": np.arange(1, 5) * 0.01},
        {"duration_s": 1.0, "inputs": {"supply_hz": np.ones(4)}},
        {"time_s": np.arange(1, 5) * 0.01, "output_rate_hz": 10.0},
    ],
)
def test_simulate_refuses_an_ambiguous_request(kwargs):
    with pytest.raises(ConfigError):
        simulate(FA320A, **kwargs)
