"""A new drive-train element written in one place: a flexible coupling (the worked example
of docs/mechanics.md, "Adding an element").

The element is the one class below: a :class:`TorsionalCoupling` with its own fields and its
damping law. :func:`register_coupling` makes it the ``[[flexible_coupling]]`` tables of a
drive-train file; the assembly, the kinematics, the start state and the reduction take it as
they take a shaft. The checks are physics: the two-inertia natural frequency and the energy
balance of the simulated run.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import pytest

from drafttwin.errors import ConfigError
from drafttwin.mechanics import DriveTrain, reduce, simulate
from drafttwin.mechanics.components import (
    NonNegative,
    TorsionalCoupling,
    register_coupling,
    unregister_coupling,
)
from drafttwin.mechanics.steady_state import eigenfrequencies_hz


class FlexibleCoupling(TorsionalCoupling):
    """Elastomer coupling: linear torsional stiffness, viscous damping given directly."""

    damping_nms_per_rad: NonNegative = 0.0

    def damping_nms(self, ja: float, jb: float) -> float:
        return self.damping_nms_per_rad


J1, J2 = 0.02, 0.05  # kg m^2: the driving hub, the driven load
K_NM = 200.0  # N m/rad
TORQUE_NM = 1.5  # a constant torque on the hub from t = 0
OMEGA_N = math.sqrt(K_NM * (J1 + J2) / (J1 * J2))  # rad/s, the closed form
RPM = math.pi / 30.0


@pytest.fixture(scope="module", autouse=True)
def _registered() -> Iterator[None]:
    register_coupling("flexible_coupling", FlexibleCoupling)
    yield
    unregister_coupling("flexible_coupling")


def _toml(tmp_path, damping: float) -> DriveTrain:
    path = tmp_path / "flex.toml"
    path.write_text(f"""
[train]
name = "two_inertias"

[[inertia]]
name = "hub"
inertia_kgm2 = {J1}

[[inertia]]
name = "load"
inertia_kgm2 = {J2}

[[flexible_coupling]]
name = "flex"
a = "hub"
b = "load"
stiffness_nm_per_rad = {K_NM}
damping_nms_per_rad = {damping}

[[torque]]
name = "drive"
node = "hub"
times_s = [0.0, 100.0]
torque_nm = [{TORQUE_NM}, {TORQUE_NM}]

[solver]
dt_s = 2.0e-5
output_rate_hz = 4000.0
settle_s = 0.0
""")
    return DriveTrain.from_toml(path)


def _zeta(c: float) -> float:
    return c / (2 * math.sqrt(K_NM * J1 * J2 / (J1 + J2)))


def test_the_element_becomes_a_spring_row_and_round_trips(tmp_path) -> None:
    train = _toml(tmp_path, damping=0.05)
    (kind, flex), *rest = train.spec.couplings()
    assert kind == "flexible_coupling" and isinstance(flex, FlexibleCoupling) and not rest
    tab = train.tables()
    np.testing.assert_array_equal(tab.spring_i, [[0, 1]])
    np.testing.assert_array_equal(tab.spring_f, [[K_NM, 0.05]])
    again = DriveTrain.from_dict(train.to_dict())
    assert again.to_dict()["flexible_coupling"] == [flex.model_dump()]
    np.testing.assert_array_equal(again.tables().spring_f, tab.spring_f)
    # the linearised train: one rigid-body mode and the closed-form twist mode
    assert eigenfrequencies_hz(train)[-1] == pytest.approx(OMEGA_N / (2 * math.pi), rel=1e-9)


def test_bad_values_are_named_like_built_in_elements(tmp_path) -> None:
    raw = _toml(tmp_path, damping=0.0).to_dict()
    raw["flexible_coupling"][0]["stiffness_nm_per_rad"] = -1.0
    with pytest.raises(ConfigError, match="stiffness_nm_per_rad") as err:
        DriveTrain.from_dict(raw)
    assert err.value.where == "flexible_coupling 'flex'"
    raw["flexible_coupling"][0].update(stiffness_nm_per_rad=K_NM, b="nowhere")
    with pytest.raises(ConfigError, match="unknown node 'nowhere'"):
        DriveTrain.from_dict(raw)
    unregister_coupling("flexible_coupling")
    try:
        with pytest.raises(ConfigError, match="unknown component type 'flexible_coupling'"):
            DriveTrain.from_dict(raw)
    finally:
        register_coupling("flexible_coupling", FlexibleCoupling)
    with pytest.raises(ValueError, match="taken"):
        register_coupling("shaft", FlexibleCoupling)


def test_simulated_twist_oscillates_at_the_two_inertia_frequency(tmp_path) -> None:
    c = 2 * 0.01 * math.sqrt(K_NM * J1 * J2 / (J1 + J2))  # 1 % of critical
    run = simulate(_toml(tmp_path, damping=c), 1.0, from_rest=True)
    rel = (run.point_rpm[:, 0] - run.point_rpm[:, 1]) * RPM  # twist rate, rad/s
    t = run.time_s
    down = np.flatnonzero(np.diff(np.sign(rel)) != 0)
    crossings = t[down] - rel[down] * (t[down + 1] - t[down]) / (rel[down + 1] - rel[down])
    assert len(crossings) > 30
    omega = math.pi / np.mean(np.diff(crossings))
    assert omega == pytest.approx(OMEGA_N, rel=1e-2)
    assert omega == pytest.approx(OMEGA_N * math.sqrt(1 - _zeta(c) ** 2), rel=2e-3)


def test_input_power_goes_into_kinetic_potential_and_damping(tmp_path) -> None:
    c = 0.2  # N m s/rad: 6 % of critical, the transient is gone after a second
    run = simulate(_toml(tmp_path, damping=c), 1.0, from_rest=True, angles=True)
    assert run.angle_rad is not None
    w = run.point_rpm * RPM
    twist = run.angle_rad[1:, 0] - run.angle_rad[1:, 1]
    kinetic = 0.5 * (J1 * w[:, 0] ** 2 + J2 * w[:, 1] ** 2)
    potential = 0.5 * K_NM * twist**2
    work, damped = run.energy_j[:, 4], run.energy_j[:, 3]
    # the external torque's work is the torque times the hub's angle
    np.testing.assert_allclose(work, TORQUE_NM * run.angle_rad[1:, 0], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(work, kinetic + potential + damped, rtol=1e-8, atol=1e-12)
    # the dissipation is c times the integral of the squared twist rate
    rel = w[:, 0] - w[:, 1]
    trapz = np.concatenate(
        [[0.0], np.cumsum(0.5 * (rel[1:] ** 2 + rel[:-1] ** 2) * np.diff(run.time_s))]
    )
    np.testing.assert_allclose(damped - damped[0], c * trapz, rtol=2e-3, atol=1e-4 * damped[-1])
    # the twist settles on the static value T J2 / ((J1 + J2) k), and a load stepped onto a
    # spring loses to damping exactly the strain energy it leaves in it
    static = TORQUE_NM * J2 / ((J1 + J2) * K_NM)
    assert twist[-1] == pytest.approx(static, rel=2e-3)  # e^-7 of the transient is left
    assert damped[-1] == pytest.approx(0.5 * K_NM * static**2, rel=1e-3)


def test_the_reduction_makes_a_stiff_coupling_rigid(tmp_path) -> None:
    train = reduce(_toml(tmp_path, damping=0.05), cutoff_hz=1.0)
    assert train.reduction is not None and train.reduction.rigid == ("flex",)
    run = simulate(train, 0.2, from_rest=True)
    rigid = TORQUE_NM * run.time_s / (J1 + J2)  # both turn as one body, rad/s
    np.testing.assert_allclose(run.point_rpm * RPM, np.c_[rigid, rigid], rtol=1e-9)
