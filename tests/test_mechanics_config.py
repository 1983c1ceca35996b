"""Bad drive-train configs are refused with one clear message; the CLI exits 2, no traceback."""

import tomllib
from pathlib import Path

import pytest
from typer.testing import CliRunner

from drafttwin.cli import app
from drafttwin.errors import ConfigError
from drafttwin.mechanics import DriveTrain
from drafttwin.mechanics.config import preset_path

PRESET_TEXT = preset_path("fa320a").read_text()


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "train.toml"
    path.write_text(text)
    return path


def _refused(tmp_path: Path, text: str) -> str:
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        DriveTrain.from_toml(path)
    msg = info.value.message
    assert str(path) in msg  # names the file
    assert "fix:" in msg  # says what to do
    return msg


def test_preset_file_loads(tmp_path):
    train = DriveTrain.from_toml(_write(tmp_path, PRESET_TEXT))
    assert train.to_dict() == DriveTrain.preset("fa320a").to_dict()


def test_unknown_component_type(tmp_path):
    msg = _refused(tmp_path, PRESET_TEXT + '\n[[flywheel]]\nname = "x"\n')
    assert "unknown component type 'flywheel'" in msg


def test_unknown_node(tmp_path):
    text = PRESET_TEXT.replace('driven = "front_drive"', 'driven = "front_drve"', 1)
    msg = _refused(tmp_path, text)
    assert "gear 'A-B'" in msg and "'driven'" in msg and "front_drve" in msg


def test_disconnected_graph(tmp_path):
    msg = _refused(tmp_path, PRESET_TEXT + '\n[[inertia]]\nname = "loose"\ninertia_kgm2 = 0.01\n')
    assert "loose" in msg and "not connected" in msg


def test_non_positive_inertia(tmp_path):
    text = PRESET_TEXT.replace("inertia_kgm2 = 0.0032", "inertia_kgm2 = 0.0", 1)
    msg = _refused(tmp_path, text)
    assert "inertia 'front_roller'" in msg and "inertia_kgm2" in msg and "greater than 0" in msg


def test_non_positive_stiffness(tmp_path):
    text = PRESET_TEXT.replace("stiffness_nm_per_rad = 1.2e4", "stiffness_nm_per_rad = -1.2e4", 1)
    msg = _refused(tmp_path, text)
    assert "shaft 'second_roller_twist'" in msg and "stiffness_nm_per_rad" in msg


def test_missing_field(tmp_path):
    text = PRESET_TEXT.replace("span_stiffness_n_per_m = 3.0e5", "", 1)
    msg = _refused(tmp_path, text)
    assert "belt 'main_belt'" in msg and "'span_stiffness_n_per_m' is missing" in msg


def test_a_file_without_inertias_says_so_not_field_blank(tmp_path):
    """An empty file (or one with only [train]) had been answered "field '' is missing"."""
    assert "declares no drive train (no inertias, couplings or rollers)" in _refused(tmp_path, "")
    msg = _refused(tmp_path, '[train]\nname = "x"\n')
    assert "no [[inertia]] declared" in msg and "field ''" not in msg


def test_mistyped_field(tmp_path):
    text = PRESET_TEXT.replace("driver_teeth = 24", 'driver_teeth = "twenty-four"', 1)
    msg = _refused(tmp_path, text)
    assert "gear 'A-B'" in msg and "driver_teeth" in msg and "twenty-four" in msg


def test_misspelled_field(tmp_path):
    text = PRESET_TEXT.replace("pitch_mm = 12.7", "pich_mm = 12.7", 1)
    msg = _refused(tmp_path, text)
    assert "chain 'rear_chain'" in msg and "unknown field 'pich_mm'" in msg


def test_invalid_toml(tmp_path):
    msg = _refused(tmp_path, PRESET_TEXT + "\n[[gear]\n")
    assert "not valid TOML" in msg


def test_every_refusal_exits_2_without_traceback(tmp_path):
    runner = CliRunner()
    bad = PRESET_TEXT.replace("inertia_kgm2 = 0.0032", "inertia_kgm2 = -1", 1)
    path = _write(tmp_path, bad)
    for args in (["kinematics", "--config", str(path)],
                 ["simulate", "--config", str(path), "--duration", "0.1"],
                 ["simulate", "--preset", "fa999"],
                 ["kinematics", "--config", str(tmp_path / "missing.toml")]):  # fmt: skip
        result = runner.invoke(app, args)
        assert result.exit_code == 2, (args, result.output)
        assert "Traceback" not in result.output


def test_simulate_refuses_bad_output_suffix_and_writes_nothing(tmp_path):
    out = tmp_path / "speeds.xlsx"
    result = CliRunner().invoke(app, ["simulate", "--duration", "0.01", "--out", str(out)])
    assert result.exit_code == 2
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_kinematics_json_fields():
    import json

    result = CliRunner().invoke(app, ["kinematics", "--preset", "fa320a", "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    assert set(data["drafts"]) >= {"total", "break", "middle", "main"}
    for r in ("front", "second", "third", "back"):
        assert set(data["rollers"][r]) >= {"rpm", "diameter_mm", "surface_speed_m_min"}
    assert data["delivery_speed_m_min"] == pytest.approx(256.61, rel=5e-3)


def test_kinematics_json_carries_the_output_channels_the_text_shows():
    """README promises a train's output channels at the running point; --json left them out."""
    import json

    from drafttwin.mechanics import operating_point
    from drafttwin.mechanics.steady_state import RPM

    belt = Path(__file__).resolve().parents[1] / "docs" / "examples" / "belt_drive.toml"
    result = CliRunner().invoke(app, ["kinematics", "--config", str(belt), "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    (channel,) = data["operating_point"]["output_channels"].items()
    train = DriveTrain.from_toml(belt)
    flywheel_rad_s = operating_point(train).node_speed_rad_s[train.node_index("flywheel")]
    assert channel[0] == "y" and channel[1]["unit"] == "rad/s" and channel[1]["node"] == "flywheel"
    assert channel[1]["running"] == pytest.approx(flywheel_rad_s, rel=1e-9)
    op = data["operating_point"]  # 90/180-mm pulleys: half the motor's speed, less the creep
    expected_rpm = op["motor_rpm"] * 90 / 180 * (1 - op["belt_creep"]["v_belt"])
    assert flywheel_rad_s * RPM == pytest.approx(expected_rpm, rel=1e-6)
    assert data["input_channels"] == {"u": {"drives": "supply_hz", "node": None}}
    text = CliRunner().invoke(app, ["kinematics", "--config", str(belt)]).output
    assert f"{flywheel_rad_s:.4g}" in text


def test_simulate_writes_csv_and_parquet(tmp_path):
    import pandas as pd

    for suffix in (".csv", ".parquet"):
        out = tmp_path / f"sim{suffix}"
        result = CliRunner().invoke(app, ["simulate", "--duration", "0.2", "--rate", "100",
                                          "--out", str(out), "--quiet"])  # fmt: skip
        assert result.exit_code == 0, result.output
        frame = pd.read_csv(out) if suffix == ".csv" else pd.read_parquet(out)
        assert list(frame.columns) == ["time", "front", "second", "third", "back", "motor"]
        assert len(frame) == 20


def test_preset_toml_is_data_not_code():
    # the preset parses as plain TOML (configs are data, never executed)
    assert tomllib.loads(PRESET_TEXT)["train"]["name"] == "fa320a"


def test_channel_tables_in_a_file_are_checked(tmp_path):
    inputs = '\n[[input]]\nchannel = "force"\ndrives = "torque"\nnode = "front_rollr"\n'
    msg = _refused(tmp_path, PRESET_TEXT + inputs)
    assert "input 'force'" in msg and "'node'" in msg and "front_rollr" in msg
    assert "fix: use one of the declared inertias" in msg
    outputs = '\n[[output]]\nchannel = "v"\nnode = "motor"\nunit = "m/min"\n'
    msg = _refused(tmp_path, PRESET_TEXT + outputs)
    assert "output 'v'" in msg and "m/min" in msg and "node 'motor'" in msg
    result = CliRunner().invoke(app, ["kinematics", "--config", str(tmp_path / "train.toml")])
    assert result.exit_code == 2 and "Traceback" not in result.output
    good = '\n[[input]]\nchannel = "u"\ndrives = "supply_hz"\ngain = 5.0\nhold = "zoh"\n'
    train = DriveTrain.from_toml(
        _write(tmp_path, PRESET_TEXT + good + outputs.replace("motor", "front"))
    )
    (u,) = train.input_channels()
    assert (u.channel, u.gain, u.hold) == ("u", 5.0, "zoh")
    assert [(o.channel, o.node, o.unit) for o in train.output_channels()] == [
        ("v", "front_roller", "m/min")]  # fmt: skip


def test_drafting_zone_must_join_two_declared_rollers(tmp_path):
    text = PRESET_TEXT.replace('feeding = "back"', 'feeding = "third"', 1)
    msg = _refused(tmp_path, text)
    assert "drafting_zone 'break'" in msg and "same roller" in msg
    raw = DriveTrain.preset("fa320a").to_dict()
    raw["roller"] = [r for r in raw["roller"] if r["name"] != "back"]
    raw["output"] = [o for o in raw.get("output", []) if o.get("node") != "back"]
    with pytest.raises(ConfigError, match="roller 'back', which is not declared"):
        DriveTrain.from_dict(raw)


def test_kinematics_of_a_train_without_a_motor_is_text_unless_json(tmp_path):
    """It printed JSON without --json; and a train run below its rated supply was said to
    run 'at the rated supply'."""
    import json
    import re

    belt = (
        Path(__file__).resolve().parents[1] / "docs" / "examples" / "belt_drive.toml"
    ).read_text()
    no_motor = re.sub(r"\n\[motor\]\n(?:[^\[\n][^\n]*\n|\n)*", "\n", belt)
    no_motor = re.sub(r"\n\[\[input\]\]\n(?:[^\[\n][^\n]*\n|\n)*", "\n", no_motor)
    path = tmp_path / "no_motor.toml"
    path.write_text(no_motor)
    runner = CliRunner()
    text = runner.invoke(app, ["kinematics", "--config", str(path), "--motor-rpm", "1400"])
    assert text.exit_code == 0, text.output
    assert not text.output.lstrip().startswith("{") and "no [motor]" in text.output
    data = runner.invoke(app, ["kinematics", "--config", str(path), "--motor-rpm", "1400",
                               "--json"])  # fmt: skip
    assert json.loads(data.output)["motor_rpm"] == 1400
    slow = tmp_path / "slow.toml"
    slow.write_text(belt.replace("\nsupply_hz = 50.0 ", "\nsupply_hz = 25.0 ", 1))
    said = runner.invoke(app, ["kinematics", "--config", str(slow)]).output
    assert "at a 25-Hz supply" in " ".join(said.split()) and "rated supply" not in said


def test_a_misspelt_required_field_is_named(tmp_path):
    """It read "field 'span_stiffness_n_per_m' is missing (and 1 more problem)"."""
    text = PRESET_TEXT.replace("span_stiffness_n_per_m = 3.0e5", "span_stifness_n_per_m = 3.0e5", 1)
    msg = _refused(tmp_path, text)
    assert "'span_stifness_n_per_m' is not a field" in msg and "more problem" not in msg
    assert "correct the spelling of 'span_stifness_n_per_m' to 'span_stiffness_n_per_m'" in msg
