"""Faults injected in the plant: physics of each kind, sensor faults, labels, CLI refusals."""

import json
import re

import numpy as np
import pytest
from typer.testing import CliRunner

from drafttwin import ROLLERS
from drafttwin.cli import app
from drafttwin.errors import ConfigError
from drafttwin.mechanics import DriveTrain, operating_point
from drafttwin.mechanics import kernel as K
from drafttwin.plant import Machine, Plant
from drafttwin.plant.faults import FaultSchedule, FaultSpec, catalogue, check_faults

DUR, ONSET, SEED = 4.0, 2.0, 3
PRE, POST = slice(30, 195), slice(250, 400)  # rows before / after the onset (100 Hz)


@pytest.fixture(scope="module")
def plant():
    return Plant()


@pytest.fixture(scope="module")
def machine(plant):
    return Machine.draw(plant.train, plant.config, SEED)


@pytest.fixture(scope="module")
def healthy(plant, machine):
    return plant.run(DUR, seed=SEED, machine=machine)


def run(plant, machine, text):
    return plant.run(DUR, seed=SEED, machine=machine, faults=[FaultSpec.parse(text)])


def rel(a, b):
    return a[POST].mean(axis=0) / b[POST].mean(axis=0) - 1.0


def predicted_change(machine, edit):
    """Relative roller-speed change the torque balance predicts for an edited true train,
    with the plant's mean drafting forces (the plant draws them as a process around them)."""
    raw = machine.train.to_dict()
    raw["drafting_zone"] = DriveTrain.preset("fa320a").to_dict()["drafting_zone"]
    before = operating_point(DriveTrain.from_dict(raw)).roller_rpm
    edit(raw)
    after = operating_point(DriveTrain.from_dict(raw)).roller_rpm
    return np.array([after[r] / before[r] - 1.0 for r in ROLLERS])


def test_empty_fault_list_is_bit_identical(plant, machine, healthy):
    again = plant.run(DUR, seed=SEED, machine=machine, faults=[])
    assert np.array_equal(again.series.values, healthy.series.values, equal_nan=True)
    assert np.array_equal(again.true_rpm, healthy.true_rpm)
    assert np.array_equal(again.true_motor_rpm, healthy.true_motor_rpm)
    assert again.info == healthy.info and healthy.info["faults"] == []


def test_bearing_friction_lowers_speeds_as_torque_balance_predicts(plant, machine, healthy):
    s = 10.0
    rec = run(plant, machine, f"front_roller:bearing_friction:severity={s}:onset={ONSET}")
    assert np.array_equal(rec.true_rpm[:200], healthy.true_rpm[:200])  # nothing before onset

    def edit(raw):
        for b in raw["bearing"]:
            if b["node"] == "front_roller":
                b["coulomb_torque_nm"] *= 1 + s
                b["viscous_nms"] *= 1 + s

    want = predicted_change(machine, edit)
    got = rel(rec.true_rpm, healthy.true_rpm)
    assert np.all(want < -1e-4)  # a measurable slow-down on every roller
    np.testing.assert_allclose(got, want, rtol=0.05)


def test_top_roller_load_loss_speeds_up_as_predicted(plant, machine, healthy):
    s = 0.5
    rec = run(plant, machine, f"front:load_loss:severity={s}:onset={ONSET}")

    def edit(raw):
        for r in raw["roller"]:
            if r["name"] == "front":
                r["top_load_per_side_n"] *= 1 - s

    want = predicted_change(machine, edit)
    assert np.all(want > 5e-4)
    np.testing.assert_allclose(rel(rec.true_rpm, healthy.true_rpm), want, rtol=0.05)


def test_belt_wear_raises_creep_as_predicted(plant, machine, healthy):
    s = 0.5
    rec = run(plant, machine, f"main_belt:belt_wear:severity={s}:onset={ONSET}")

    def edit(raw):
        raw["belt"][0]["axial_rigidity_n"] *= 1 - s

    want = predicted_change(machine, edit)
    np.testing.assert_allclose(rel(rec.true_rpm, healthy.true_rpm), want, rtol=0.05)
    motor = rec.true_motor_rpm[POST].mean() / healthy.true_motor_rpm[POST].mean() - 1
    assert abs(motor) < 0.05 * abs(want[0])  # the motor does not see it: the belt slips more


def test_rotor_resistance_scales_the_slip(plant, machine, healthy):
    s = 0.2
    rec = run(plant, machine, f"motor:rotor_resistance:severity={s}:onset={ONSET}")
    sync = healthy.series.inputs["supply_hz"][POST] * 60 / 2  # 4-pole motor, rpm
    slip_h = (sync - healthy.true_motor_rpm[POST]).mean()
    slip_f = (sync - rec.true_motor_rpm[POST]).mean()
    assert slip_f / slip_h == pytest.approx(1 + s, rel=0.02)  # slip ~ R_r at light load


def test_positive_drives_keep_ratios_under_wear_and_elongation(plant, machine, healthy):
    for text in ("E-F:wear:severity=150:onset=2", "rear_chain:elongation:severity=1.5:onset=2"):
        rec = run(plant, machine, text)
        assert not np.array_equal(rec.true_rpm, healthy.true_rpm), text  # the train changed ...
        assert np.all(np.abs(rel(rec.true_rpm, healthy.true_rpm)) < 2e-5), text  # ... its means not


def test_fault_tables_change_the_named_parameters(plant, machine):
    train = machine.train
    faults = check_faults([FaultSpec.parse(t) for t in (
        "E-F:wear:severity=40:onset=1", "A-B:crack:severity=0.5:onset=1",
        "rear_chain:elongation:severity=1:onset=1:ramp=10", "motor:torque_loss:severity=0.2:onset=1",
    )], train)  # fmt: skip
    sched = FaultSchedule(train, faults)
    base = train.tables()
    assert sched(0.5) is base  # before onset: the healthy tables themselves
    tab = sched(6.0)  # wear, crack, torque loss full; elongation half way
    ef, ab = 2, 0
    assert tab.gear_f[ef, K.G_B] - base.gear_f[ef, K.G_B] == pytest.approx(40e-6)
    assert tab.gear_f[ef, K.G_K] / base.gear_f[ef, K.G_K] == pytest.approx(1 - 40 / 200)
    assert tab.gear_f[ab, K.G_CRACK] == 0.5 and base.gear_f[ab, K.G_CRACK] == 0.0
    assert tab.gear_f[ab, K.G_CRACK_SPAN] == pytest.approx(1.6 * 2 * np.pi / 24)
    # half way up the ramp: 0.5 %, of which each span takes half
    slack = 0.5 * 0.005 * 62 * 12.7e-3 * base.chain_f[0, K.CH_K]
    assert tab.chain_f[0, K.CH_T0] == pytest.approx(base.chain_f[0, K.CH_T0] - slack)
    assert tab.motor_f[0, K.MOT_TK] == pytest.approx(0.8 * base.motor_f[0, K.MOT_TK])


def test_crack_modulates_once_per_driver_revolution(plant, machine, healthy):
    rec = plant.run(DUR, rate_hz=1000.0, seed=SEED, machine=machine,
                    faults=[FaultSpec.parse("G-H:crack:severity=0.9:onset=0")])  # fmt: skip
    ref = plant.run(DUR, rate_hz=1000.0, seed=SEED, machine=machine)
    diff = rec.true_rpm[:, 3] - ref.true_rpm[:, 3]  # back roller, behind the G-H mesh
    assert np.abs(diff).max() > 0
    spec = np.abs(np.fft.rfft(diff[500:] - diff[500:].mean()))
    freqs = np.fft.rfftfreq(len(diff) - 500, 1e-3)
    rear_hz = operating_point(machine.train).node_speed_rad_s[
        machine.train.node_index("rear_shaft")
    ] / (2 * np.pi)
    peak = freqs[np.argmax(spec[freqs < 100])]
    # a comb of orders of the driver gear G (it turns with the rear shaft), not of the roller
    order = peak / rear_hz
    assert order >= 0.9 and abs(order - round(order)) < 0.05


def test_sensor_faults_touch_one_channel_not_the_machine(plant, machine, healthy):
    rec = plant.run(DUR, seed=SEED, machine=machine, faults=[
        FaultSpec.parse("second:gain:severity=0.01:onset=2"),
        FaultSpec.parse("third:stuck:severity=1:onset=2.5"),
        FaultSpec.parse("back:dropout:severity=1:onset=3"),
    ])  # fmt: skip
    assert np.array_equal(rec.true_rpm, healthy.true_rpm)  # the machine runs as before
    m, h = rec.series.values, healthy.series.values
    ok = np.isfinite(h[:, 1])
    ratio = m[200:, 1][ok[200:]] / h[200:, 1][ok[200:]]
    np.testing.assert_allclose(ratio, 1.01, rtol=1e-12)
    stuck = m[249:349, 2][np.isfinite(m[249:349, 2])]  # t = 2.50 .. 3.49 s
    assert np.all(stuck == stuck[0]) and np.isfinite(m[350:, 2]).any()
    assert np.isnan(m[300:, 3]).all() and not np.isnan(h[300:, 3]).all()
    assert np.array_equal(m[:, 0], h[:, 0], equal_nan=True)  # front untouched
    assert rec.missing[300:, 3].all()


def test_labels_round_trip_through_the_sidecar(plant, machine, tmp_path):
    faults = [FaultSpec.parse("front:eccentricity:severity=0.3:onset=1.1:ramp=2"),
              FaultSpec.parse("motor:gain:severity=-0.002:onset=0.5")]  # fmt: skip
    rec = plant.run(2.0, seed=SEED, machine=machine, faults=faults)
    rec.write(tmp_path / "r.parquet")
    info = json.loads((tmp_path / "r.json").read_text())
    keys = ("element", "kind", "severity", "onset_s", "ramp_s")
    back = [FaultSpec(**{k: lab[k] for k in keys}) for lab in info["faults"]]
    assert back == faults
    assert info["faults"][0]["effective_onset_s"] == pytest.approx(1.25)  # next 0.25-s block
    assert info["faults"][1]["family"] == "sensor"


def test_bad_faults_are_refused(plant):
    cat = catalogue(plant.train)
    assert "E-F" in cat and "wear" in cat["E-F"] and "gain" in cat["front"]
    with pytest.raises(ConfigError, match="use one of: crack, wear, runout"):
        check_faults([FaultSpec.parse("E-F:rust:severity=1:onset=0")], plant.train)
    with pytest.raises(ConfigError, match="out of range"):
        check_faults([FaultSpec.parse("front:load_loss:severity=1.5:onset=0")], plant.train)
    with pytest.raises(ConfigError, match="has no ramp"):
        check_faults([FaultSpec.parse("front:stuck:severity=1:onset=0:ramp=3")], plant.train)
    with pytest.raises(ConfigError, match="lacks onset"):
        FaultSpec.parse("front:stuck:severity=1")
    # in the words typed (onset=, ramp=), not pydantic's "onset_s Input should be"
    with pytest.raises(ConfigError, match="onset=-5 must be greater than or equal to 0"):
        FaultSpec.parse("main_belt:belt_wear:severity=0.5:onset=-5")
    with pytest.raises(ConfigError, match="ramp=-1 must be greater than or equal to 0"):
        FaultSpec.parse("main_belt:belt_wear:severity=0.5:onset=5:ramp=-1")


def test_cli_refuses_unknown_element_listing_valid_ones(tmp_path):
    result = CliRunner().invoke(app, ["generate", "--out", str(tmp_path / "x.csv"), "--quiet",
                                      "--duration", "1", "--fault", "Z-Z:wear:severity=1:onset=0"])  # fmt: skip
    assert result.exit_code == 2
    assert "no element 'Z-Z'" in result.output and "E-F" in result.output
    assert "Traceback" not in result.output and not (tmp_path / "x.csv").exists()


def test_cli_refuses_a_fault_after_the_records_end_and_notes_a_ramp_beyond_it(tmp_path):
    # the sidecar would label a fault the record does not hold
    result = CliRunner().invoke(app, ["generate", "--out", str(tmp_path / "x.csv"), "--quiet",
                                      "--duration", "2", "--fault", "E-F:wear:severity=60:onset=30"])  # fmt: skip
    assert result.exit_code == 2 and "starts at 30 s, not before the record's end" in result.output
    assert not (tmp_path / "x.csv").exists()
    result = CliRunner().invoke(app, ["generate", "--out", str(tmp_path / "x.csv"), "--quiet",
                                      "--duration", "2", "--fault",
                                      "E-F:wear:severity=60:onset=1:ramp=10"])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "it reaches 10% of severity 60" in result.output
    # the summary has the motor's row too (the command writes its speed)
    assert re.search(r"motor\s*│\s*14\d\d\.\d\d\s*│", result.output), result.output


def test_generate_faults_is_seeded_and_labelled(tmp_path):
    outs = []
    for k in range(2):
        out = tmp_path / f"set{k}"
        args = ["generate-faults", "--out", str(out), "--cases", "3", "--duration", "1.5",
                "--seed", "11", "--quiet"]  # fmt: skip
        result = CliRunner().invoke(app, args)
        assert result.exit_code == 0, result.output
        outs.append(out)
    a, b = (json.loads((o / "cases.json").read_text()) for o in outs)
    assert a == b and len(a["cases"]) == 3 and a["cases"][0]["faults"] == []
    assert all(len(c["faults"]) == 1 for c in a["cases"][1:])
    for c in a["cases"]:
        assert (outs[0] / c["file"]).read_bytes() == (outs[1] / c["file"]).read_bytes()
        side = json.loads((outs[0] / c["file"]).with_suffix(".json").read_text())
        assert [f["kind"] for f in side["faults"]] == [f["kind"] for f in c["faults"]]
    # each kind's severity unit is printed; a smaller set in the same folder notes the older
    kinds = {f["kind"] for c in a["cases"] for f in c["faults"]}
    assert all(f"{k} severity: " in result.output for k in kinds), result.output
    result = CliRunner().invoke(app, [*args[:4], "2", *args[5:]])
    assert result.exit_code == 0 and "1 older record(s)" in result.output, result.output
