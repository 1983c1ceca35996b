"""Kinematics of the FA320A preset and eigenfrequencies against closed forms."""

import math

import numpy as np
import pytest

from drafttwin.mechanics import DriveTrain, eigenfrequencies_hz, kinematics, operating_point
from drafttwin.mechanics.assembly import gear_base_radii_m

from ._trains import FA320A, two_inertia_gear

PAPER_DELIVERY_M_MIN = 256.61
PAPER_TOTAL_DRAFT = 6.57


def test_preset_reproduces_paper_operating_point():
    kin = kinematics(FA320A)
    assert kin.delivery_speed_m_min == pytest.approx(PAPER_DELIVERY_M_MIN, rel=5e-3)
    assert kin.drafts["total"] == pytest.approx(PAPER_TOTAL_DRAFT, rel=5e-3)
    assert 1.16 <= kin.drafts["break"] <= 1.26  # cotton break draft, domain.md [6]


def test_total_draft_is_product_of_zone_drafts_and_surface_speed_ratio():
    kin = kinematics(FA320A)
    d = kin.drafts
    assert d["total"] == pytest.approx(d["main"] * d["middle"] * d["break"], rel=1e-12)
    front, back = kin.rollers["front"], kin.rollers["back"]
    # surface speed v = n * pi * D, computed here independently of the library
    expected = (front.rpm * math.pi * 45e-3) / (back.rpm * math.pi * 35e-3)
    assert d["total"] == pytest.approx(expected, rel=1e-12)


def test_roller_speeds_follow_tooth_counts():
    kin = kinematics(FA320A, motor_rpm=1450.0)
    main_shaft = 1450.0 * 150 / 125
    assert kin.rollers["front"].rpm == pytest.approx(main_shaft * 24 / 23)
    assert kin.rollers["second"].rpm == pytest.approx(main_shaft * 24 / 23 * 21 / 43 * 25 / 51)
    back = main_shaft * 25 / 50 * 20 / 49
    assert kin.rollers["back"].rpm == pytest.approx(back)
    assert kin.rollers["third"].rpm == pytest.approx(back * 36 / 30)
    assert kin.mesh_frequencies_hz["A-B"] == pytest.approx(24 * main_shaft / 60)
    assert kin.chain_tooth_frequencies_hz["rear_chain"] == pytest.approx(25 * main_shaft / 60)


def test_two_inertia_mesh_eigenfrequency_matches_closed_form():
    j1, j2, k = 0.01, 0.002, 2.0e8
    train = DriveTrain.from_dict(two_inertia_gear(j1, j2, k))
    rb1, rb2 = gear_base_radii_m(train.spec.gear[0])
    omega = math.sqrt(k * (rb1**2 / j1 + rb2**2 / j2))
    (f,) = eigenfrequencies_hz(train)
    assert f == pytest.approx(omega / (2 * math.pi), rel=1e-9)


def test_operating_point_matches_hand_torque_balance():
    """Load torques reflected to the motor (power equivalence), then the Kloss slip."""
    train = FA320A
    op = operating_point(train)
    ratios = train.speed_ratios
    w = ratios * op.node_speed_rad_s[train.node_index("motor")]
    torque = 0.0
    for r in train.spec.roller:
        node = train.node_index(r.node)
        torque += (
            r.friction_coefficient * 2 * r.top_load_per_side_n * r.diameter_mm / 2000 * ratios[node]
        )
    for b in train.spec.bearing:
        node = train.node_index(b.node)
        torque += (b.coulomb_torque_nm + b.viscous_nms * w[node]) * ratios[node]
    rollers = {r.name: r for r in train.spec.roller}
    assert train.spec.drafting_zone  # the preset's sliver load: F (v_delivering - v_feeding)
    for z in train.spec.drafting_zone:
        fast, slow = rollers[z.delivering], rollers[z.feeding]
        v = [r.diameter_mm / 2000 * ratios[train.node_index(r.node)] for r in (fast, slow)]
        torque += z.force_n * (v[0] - v[1])
    # belt creep costs a little extra power: within its size (< 0.1 %)
    assert op.motor_torque_nm == pytest.approx(torque, rel=1e-3)
    m = train.spec.motor
    t_n = m.rated_power_w / (m.rated_rpm * math.pi / 30)
    s_n = 1 - m.rated_rpm / 1500
    lam = m.breakdown_torque_ratio
    slip_k = s_n * (lam + math.sqrt(lam**2 - 1)) * 1500  # rpm, V/f: slip speed is what counts
    x = op.motor_torque_nm / (lam * t_n)
    slip_rpm = slip_k * (1 - math.sqrt(1 - x * x)) / x
    assert op.motor_rpm == pytest.approx(120 * m.supply_hz / m.poles - slip_rpm, rel=1e-9)


def test_three_inertia_shaft_chain_eigenfrequencies_match_the_characteristic_equation():
    """Free-free chain J1 -k1- J2 -k2- J3: the two elastic modes solve
    w^4 - w^2 (k1/J1 + k1/J2 + k2/J2 + k2/J3) + k1 k2 (J1 + J2 + J3) / (J1 J2 J3) = 0."""
    j1, j2, j3, k1, k2 = 0.02, 0.005, 0.01, 3.0e4, 1.2e4
    train = DriveTrain.from_dict({
        "inertia": [{"name": n, "inertia_kgm2": j} for n, j in (("a", j1), ("b", j2), ("c", j3))],
        "shaft": [{"name": "ab", "a": "a", "b": "b", "stiffness_nm_per_rad": k1},
                  {"name": "bc", "a": "b", "b": "c", "stiffness_nm_per_rad": k2}],
    })  # fmt: skip
    b = k1 / j1 + k1 / j2 + k2 / j2 + k2 / j3
    c = k1 * k2 * (j1 + j2 + j3) / (j1 * j2 * j3)
    w2 = np.sort(np.roots([1.0, -b, c]).real)
    np.testing.assert_allclose(eigenfrequencies_hz(train), np.sqrt(w2) / (2 * math.pi), rtol=1e-9)
    assert len(kinematics(FA320A).eigenfrequencies_hz) == len(FA320A.node_names) - 1
