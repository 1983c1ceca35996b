"""What a motor torque channel would add (studies/faults/torque_channel.py), and the plant's
true motor torque it is measured against."""

import numpy as np
import pytest

from drafttwin.mechanics import DriveTrain, operating_point
from drafttwin.studies.faults.torque_channel import sensitivities


def test_a_bearing_drag_moves_the_torque_by_the_drag_and_the_speeds_by_the_slip():
    train = DriveTrain.preset("fa320a")
    rows = {(r["cause"], r["level"]): r for r in sensitivities(train, 1e-4, 1e-2)}
    motor = rows[("motor:bearing_friction", "moderate")]  # severity 5: drag x 6
    op = operating_point(train)
    bearing = next(b for b in train.spec.bearing if b.node == "motor")
    omega = op.motor_rpm * np.pi / 30.0
    added = 5.0 * (bearing.coulomb_torque_nm + bearing.viscous_nms * omega)
    assert motor["torque_rel"] == pytest.approx(added / op.motor_torque_nm, rel=0.01)
    assert motor["torque_z"] == pytest.approx(motor["torque_rel"] / 1e-2)
    for (cause, _), r in rows.items():
        if cause.endswith((":bearing_friction", ":load_loss")):
            # a load fault: torque and speeds move opposite ways, the speeds far less
            assert np.sign(r["torque_rel"]) == -np.sign(r["rollers_rel"]) != 0
            assert abs(r["rollers_rel"]) < 0.01 * abs(r["torque_rel"])
        if cause.endswith((":wear", ":elongation")):  # lost motion: no torque, no speed
            assert r["torque_rel"] == 0 and r["rollers_rel"] == 0
    assert not any(c.endswith(":gain") for c, _ in rows)  # sensor faults are not elements


def test_the_plant_records_the_motor_torque_a_bearing_drag_raises():
    from drafttwin.plant import Plant
    from drafttwin.plant.faults import FaultSpec

    rec = Plant().run(8.0, 100.0, seed=4,
                      faults=[FaultSpec.parse("motor:bearing_friction:severity=5:onset=4")])  # fmt: skip
    torque = rec.true_motor_torque_nm
    assert torque.shape == rec.true_motor_rpm.shape and np.isfinite(torque).all()
    before, after = torque[100:400].mean(), torque[500:].mean()
    train = DriveTrain.from_dict(rec.info["true_train"])
    bearing = next(b for b in train.spec.bearing if b.node == "motor")
    omega = rec.true_motor_rpm[500:].mean() * np.pi / 30.0
    added = 5.0 * (bearing.coulomb_torque_nm + bearing.viscous_nms * omega)
    assert after - before == pytest.approx(added, rel=0.08)  # measured 0.96 of it
