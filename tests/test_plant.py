"""Plant emulator: reproducibility, the shipped data set, sensors, defects, scenarios."""

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from drafttwin import ROLLERS
from drafttwin.cli import app
from drafttwin.data.io import read_measurements
from drafttwin.data.preprocessing import preprocess
from drafttwin.datasets import DEFAULT, build, load_default
from drafttwin.mechanics import DriveTrain, operating_point, simulate
from drafttwin.plant import Plant, PlantConfig
from drafttwin.plant.config import Sensors
from drafttwin.plant.sensors import encoder_rpm, quantisation_step_rpm


@pytest.fixture(scope="module")
def default():
    return load_default()


def test_same_seed_byte_identical_files(tmp_path):
    runner = CliRunner()
    outs = []
    for k in range(2):
        out = tmp_path / f"run{k}" / "data.csv"
        result = runner.invoke(
            app, ["generate", "--duration", "3", "--seed", "7", "--quiet", "--out", str(out)]
        )
        assert result.exit_code == 0, result.output
        outs.append(out)
    for a_name in ("data.csv", "data.truth.csv", "data.json"):
        a = (outs[0].parent / a_name).read_bytes()
        b = (outs[1].parent / a_name).read_bytes()
        assert a == b, a_name
    other = tmp_path / "other" / "data.csv"
    runner.invoke(
        app, ["generate", "--duration", "3", "--seed", "8", "--quiet", "--out", str(other)]
    )
    assert other.read_bytes() != outs[0].read_bytes()


def test_generated_file_reads_back_with_sidecar(tmp_path):
    out = tmp_path / "d.parquet"
    result = CliRunner().invoke(
        app, ["generate", "--duration", "2", "--seed", "1", "--quiet", "--out", str(out)]
    )
    assert result.exit_code == 0, result.output
    series = read_measurements(out)
    assert series.channels == ROLLERS and len(series) == 200
    assert series.sample_rate_hz == pytest.approx(100.0)
    info = json.loads(out.with_suffix(".json").read_text())
    assert info["seed"] == 1 and info["files"]["truth"] == "d.truth.parquet"
    assert set(info["true_train"]) >= {"motor", "gear", "roller"}
    truth = pd.read_parquet(tmp_path / "d.truth.parquet")
    assert {"true_front", "missing_back", "outlier_third"} <= set(truth.columns)


def test_shipped_default_data_set_is_what_the_code_generates(default):
    """The first 5 s regenerated with the recorded seed equal the shipped file exactly."""
    assert len(default) == int(DEFAULT["duration_s"] * DEFAULT["rate_hz"])
    frame, _ = build(duration_s=5.0)
    n = len(frame)
    np.testing.assert_array_equal(frame[list(ROLLERS)].to_numpy(), default.values[:n])
    np.testing.assert_array_equal(
        frame[[f"true_{r}" for r in ROLLERS]].to_numpy(), default.truth[:n]
    )


def test_encoder_quantisation_and_sensor_error(default):
    truth = default.truth
    ok = ~np.isnan(default.values) & ~default.metadata["outlier_mask"]
    step = quantisation_step_rpm(Sensors(), 100.0)
    assert step == pytest.approx(0.6)
    for j in range(4):
        err = (default.values[:, j] - truth[:, j])[ok[:, j]]
        # pulse counting: error of a difference of two floors, at least step/sqrt(6)
        assert np.sqrt(np.mean(err**2)) >= 0.9 * step / np.sqrt(6)
        assert np.abs(err).max() < 10 * step


def test_encoder_counts_whole_edges():
    rng = np.random.default_rng(0)
    true = np.full((1000, 1), 355.0) + rng.normal(0, 0.2, (1000, 1))
    cfg = Sensors(clock_jitter_s=0.0)
    rpm = encoder_rpm(true, 0.01, cfg, rng)
    counts = rpm / 60.0 * 0.01 * cfg.pulses_per_rev * cfg.quadrature
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)
    # the counter loses nothing: total counted revolutions match the true ones within one edge
    assert abs(rpm.sum() - true.sum()) / 60.0 * 0.01 < 2.0 / (cfg.pulses_per_rev * cfg.quadrature)


def test_injected_defects_are_found_and_repaired(default):
    """Preprocessing fills every dropped sample and smooths the injected spikes."""
    clean, report = preprocess(default)
    assert not np.isnan(clean.values).any()
    np.testing.assert_array_equal(report.missing, default.metadata["missing_mask"])
    injected = default.metadata["outlier_mask"]
    found = report.outliers
    assert injected.sum() > 20
    recall = (found & injected).sum() / injected.sum()
    precision = (found & injected).sum() / max(found.sum(), 1)
    assert recall >= 0.95 and precision >= 0.95
    truth = default.truth
    rel = np.abs(clean.values - truth) / truth
    assert rel.max() < 0.01  # no spike survives; repaired samples are near the truth


def test_plant_differs_from_the_nominal_model_but_not_wildly(default):
    nominal = DriveTrain.preset("fa320a")
    mech = simulate(nominal, time_s=default.time_s[:2000]).roller_rpm()
    truth = default.truth[:2000]
    rel = np.abs(mech.mean(axis=0) - truth.mean(axis=0)) / truth.mean(axis=0)
    assert np.all(rel > 1e-5)  # true parameters and loads differ from the nominal ones
    assert np.all(rel < 5e-3)  # but the machine is the same machine
    assert np.all(truth.std(axis=0) > mech.std(axis=0))  # the plant has more going on


def test_startup_scenario_reaches_operating_speed():
    rec = Plant().run(12.0, 100.0, seed=3, scenario="startup")
    front = rec.true_rpm[:, 0]
    assert front[:50].max() < 5.0  # at rest before the ramp
    target = operating_point(DriveTrain.preset("fa320a")).roller_rpm["front"]
    assert front[-100:].mean() == pytest.approx(target, rel=5e-3)
    assert np.all(np.diff(rec.series.inputs["supply_hz"]) >= 0)


def test_speed_change_scenario_lowers_speed_by_15_percent():
    rec = Plant().run(8.0, 100.0, seed=4, scenario="speed-change")
    before = rec.true_rpm[200:350, 0].mean()
    after = rec.true_rpm[-100:, 0].mean()
    assert after / before == pytest.approx(0.85, abs=3e-3)


def test_drafting_force_brakes_front_and_drives_back():
    quiet = PlantConfig(sensors=Sensors(missing_rate=0, burst_rate_per_min=0, outlier_rate=0))
    cfg = quiet.model_copy(
        update={
            "drafting_force": quiet.drafting_force.model_copy(update={"main_zone_mean_n": 30.0})
        }
    )
    base = Plant(config=quiet).run(2.0, 100.0, seed=5).true_rpm.mean(axis=0)
    more = Plant(config=cfg).run(2.0, 100.0, seed=5).true_rpm.mean(axis=0)
    # a larger main-zone force loads the whole train: every roller runs (slightly) slower
    assert np.all(more < base)


def test_unknown_scenario_refused_and_nothing_written(tmp_path):
    out = tmp_path / "x.csv"
    result = CliRunner().invoke(app, ["generate", "--scenario", "warp", "--out", str(out)])
    assert result.exit_code == 2 and "unknown scenario" in result.output
    assert list(tmp_path.iterdir()) == []


def _generate(tmp_path, name, *extra):
    out = tmp_path / name
    result = CliRunner().invoke(
        app, ["generate", "--duration", "2", "--quiet", "--out", str(out), *extra]
    )
    return out, result


def test_two_records_of_one_machine_share_its_parameters_not_its_noise(tmp_path):
    a, ra = _generate(tmp_path, "a.csv", "--seed", "1", "--machine-seed", "7")
    b, rb = _generate(tmp_path, "b.csv", "--seed", "2", "--machine-seed", "7")
    c, rc = _generate(tmp_path, "c.csv", "--seed", "3", "--machine", str(a.with_suffix(".json")))
    d, rd = _generate(tmp_path, "d.csv", "--seed", "1")
    assert all(r.exit_code == 0 for r in (ra, rb, rc, rd)), (ra.output, rc.output)
    info = {
        k: json.loads(p.with_suffix(".json").read_text())
        for k, p in zip("abcd", (a, b, c, d), strict=True)
    }
    for k in "bc":
        assert info[k]["true_train"] == info["a"]["true_train"]
        assert info[k]["mismatch_draws"] == info["a"]["mismatch_draws"]
    assert info["d"]["mismatch_draws"] != info["a"]["mismatch_draws"]  # machine seed 1 != 7
    assert info["a"]["machine"]["seed"] == info["c"]["machine"]["seed"] == 7
    ya, yb = (pd.read_csv(p)["front"].to_numpy() for p in (a, b))
    assert not np.array_equal(ya, yb)  # other recording: other noise and drafting force
    # the default machine is the recording's own seed: what older versions generated
    e, re_ = _generate(tmp_path, "e.csv", "--seed", "1", "--machine-seed", "1")
    assert re_.exit_code == 0 and e.read_bytes() == d.read_bytes()


def test_machine_of_another_drive_train_refused_and_nothing_written(tmp_path):
    a, _ = _generate(tmp_path, "a.csv", "--seed", "1")
    sidecar = json.loads(a.with_suffix(".json").read_text())
    sidecar["true_train"]["roller"] = sidecar["true_train"]["roller"][:3]
    sidecar["true_train"]["output"] = [o for o in sidecar["true_train"].get("output", [])
                                       if o.get("name") != "back"]  # fmt: skip
    bad = tmp_path / "other.json"
    bad.write_text(json.dumps(sidecar))
    out, result = _generate(tmp_path, "x.csv", "--machine", str(bad))
    assert result.exit_code == 2 and "--machine" in result.output, result.output
    assert not out.exists()
    out, result = _generate(tmp_path, "y.csv", "--machine", str(tmp_path / "missing.json"))
    assert result.exit_code == 2 and "no such file" in result.output and not out.exists()
    out, result = _generate(tmp_path, "z.csv", "--machine", str(a.with_suffix(".json")),
                            "--machine-seed", "3")  # fmt: skip
    assert result.exit_code == 2 and "both" in result.output and not out.exists()


def test_motor_speed_is_measured_by_its_own_encoder():
    rec = Plant().run(3.0, seed=4)
    motor = rec.series.motor_rpm
    assert motor is not None
    ok = ~np.isnan(motor)
    np.testing.assert_array_equal(ok, ~rec.missing[:, 0])  # same logger rows dropped
    step = quantisation_step_rpm(PlantConfig().sensors, 100.0)
    err = motor[ok] - rec.true_motor_rpm[ok]
    # whole counts: the difference of two boundaries' fractions of a count (variance 1/6 of
    # a step squared), plus each boundary's clock jitter (2 us at 24 rev/s: 0.48 of a step)
    sensors = PlantConfig().sensors
    counts_per_rev = sensors.pulses_per_rev * sensors.quadrature
    jitter = sensors.clock_jitter_s * rec.true_motor_rpm.mean() / 60 * counts_per_rev
    assert err.std() == pytest.approx(step * math.sqrt(1 / 6 + 2 * jitter**2), rel=0.15)
    # at most one step of counts and 6 sigma of the two jitters (exceeded with a chance
    # below 1e-6 in 300 rows; 3 steps, the bound until 2026-12-01, in 2 of 6 records)
    assert np.abs(err).max() < step * (1 + 6 * math.sqrt(2) * jitter)
    assert abs(err.mean()) < 0.1 * step


def test_a_train_that_is_no_drawing_frame_is_refused_clearly(tmp_path):
    belt = Path(__file__).resolve().parents[1] / "docs" / "examples" / "belt_drive.toml"
    out, result = _generate(tmp_path, "belt.csv", "--config", str(belt))
    assert result.exit_code == 2 and "no rollers" in result.output, result.output
    assert "Traceback" not in result.output and not out.exists()
