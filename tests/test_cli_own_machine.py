"""Your own machine from the command line: named channels that are not rpm, exogenous inputs,
several records, separate test records, a simulator output file or a drive-train TOML as the
physics, and the simulation task; every refusal exits 2 with one message."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from drafttwin.cli import app

ROOT = Path(__file__).resolve().parents[1]
BELT = ROOT / "docs" / "examples" / "belt_drive.toml"
runner = CliRunner()
CHANNELS = ["--outputs", "y", "--units", "y=rad/s,u=V"]


def _ok(args: list[str]) -> str:
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    return result.stdout


def _refused(args: list[str], *needles: str) -> str:
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    for needle in needles:
        assert needle in result.output, (needle, result.output)
    return result.output


@pytest.fixture(scope="module")
def belt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Short belt-drive records (the tutorial's generator): train.csv with two records,
    test.csv, and the physics' output on both (simulator files written by predict)."""
    spec = importlib.util.spec_from_file_location(
        "belt", ROOT / "docs/examples/make_belt_records.py"
    )
    assert spec is not None and spec.loader is not None
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    folder = tmp_path_factory.mktemp("belt")
    rng = np.random.default_rng(7)
    parts = [gen.record(12.0, rng).assign(record=k) for k in (1, 2)]
    pd.concat(parts, ignore_index=True).to_csv(folder / "train.csv", index=False)
    gen.record(10.0, rng).to_csv(folder / "test.csv", index=False)
    physics = folder / "physics.dtm"
    _ok(["fit", "--model", "mechanistic", "--data", folder / "train.csv", *CHANNELS,
         "--mechanistic", f"config:{BELT}", "--train-fraction", "1", "--out", physics])  # fmt: skip
    for name in ("train", "test"):
        _ok(["predict", "--model", physics, "--data", folder / f"{name}.csv", "--out",
             folder / f"sim_{name}.csv"])  # fmt: skip
    return folder


def test_simulator_files_are_the_physics_on_each_record(belt: Path) -> None:
    sim = pd.read_csv(belt / "sim_train.csv")
    assert list(sim.columns) == ["t", "y", "record"]  # time named as the input named it
    assert sim["record"].nunique() == 2 and len(sim) == 1200
    measured = pd.read_csv(belt / "train.csv")
    np.testing.assert_array_equal(sim["t"], measured["t"])
    err = sim["y"].to_numpy() - measured["y"].to_numpy()
    assert 0.05 < np.sqrt(np.mean(err**2)) < 2.0  # the drawing's physics, not the true machine


@pytest.mark.parametrize("name", ["parallel", "md-s-l"])
def test_hybrid_simulation_on_a_separate_test_record(name: str, belt: Path) -> None:
    model = belt / f"{name}.dtm"
    fitted = json.loads(_ok([
        "fit", "--model", name, "--task", "simulation", "--data", belt / "train.csv",
        "--test-data", belt / "test.csv", *CHANNELS, "--inputs", "u", "--mechanistic",
        f"{belt / 'sim_train.csv'},{belt / 'sim_test.csv'}", "--epochs", "2", "--quiet",
        "--json", "--out", model,
    ]))  # fmt: skip
    y = fitted["channels"]["y"]
    assert fitted["task"] == "simulation" and y["unit"] == "rad/s" and y["rmse"] > 0
    assert fitted["selection"]["accumulate"]["chosen_by"] == "validation folds"
    assert fitted["split"]["mode"] == "records" and fitted["split"]["train_records"] == 2
    again = json.loads(_ok(["evaluate", "--model", model, "--test-data", belt / "test.csv",
                            "--mechanistic", belt / "sim_test.csv", "--json"]))  # fmt: skip
    assert again["channels"]["y"]["rmse"] == pytest.approx(y["rmse"], rel=1e-12)
    assert again["selection"] == fitted["selection"]
    _ok(["predict", "--model", model, "--test-data", belt / "test.csv", "--mechanistic",
         belt / "sim_test.csv", "--out", belt / f"{name}_pred.csv"])  # fmt: skip
    pred = pd.read_csv(belt / f"{name}_pred.csv")
    assert list(pred.columns) == ["t", "y"] and pred["y"].isna().sum() == 20  # init window


def test_a_drive_train_toml_feeds_a_hybrid(belt: Path) -> None:
    """--mechanistic config:FILE: the user's drive train simulated on every record,
    following the set-point channel u; the model file keeps the train."""
    model = belt / "gru_config.dtm"
    out = json.loads(_ok([
        "fit", "--model", "parallel", "--data", belt / "train.csv", "--test-data",
        belt / "test.csv", *CHANNELS, "--mechanistic", f"config:{BELT}", "--epochs", "2",
        "--quiet", "--json", "--out", model,
    ]))  # fmt: skip
    assert out["task"] == "prediction" and out["channels"]["y"]["n_scored"] > 400
    again = json.loads(
        _ok(["evaluate", "--model", model, "--test-data", belt / "test.csv", "--json"])
    )  # no --mechanistic: the train is in the model file
    assert again["channels"]["y"]["rmse"] == pytest.approx(out["channels"]["y"]["rmse"])


def test_mechanistic_alone_from_a_simulator_file(belt: Path) -> None:
    out = json.loads(_ok(["fit", "--model", "mechanistic", "--data", belt / "train.csv",
                          "--test-data", belt / "test.csv", *CHANNELS, "--mechanistic",
                          f"{belt / 'sim_train.csv'},{belt / 'sim_test.csv'}", "--json",
                          "--out", belt / "mech.dtm"]))  # fmt: skip
    sim, test = pd.read_csv(belt / "sim_test.csv"), pd.read_csv(belt / "test.csv")
    want = float(np.sqrt(np.mean((sim["y"] - test["y"]) ** 2)))
    assert out["channels"]["y"]["rmse"] == pytest.approx(want, rel=1e-9)


def test_several_data_files_are_records(belt: Path, tmp_path: Path) -> None:
    frame = pd.read_csv(belt / "train.csv")
    for k in (1, 2):
        frame[frame["record"] == k].drop(columns="record").to_csv(tmp_path / f"r{k}.csv",
                                                                 index=False)  # fmt: skip
    out = json.loads(_ok(["fit", "--model", "persistence", "--data",
                          f"{tmp_path / 'r1.csv'},{tmp_path / 'r2.csv'}", *CHANNELS,
                          "--train-fraction", "1", "--json", "--out", tmp_path / "p.dtm"]))  # fmt: skip
    assert out["split"]["train_records"] == 2 and out["split"]["train_rows"] == 1200


def test_mechanistic_on_the_default_data() -> None:
    """The FA320A defaults need no channel options; the physics follows supply_hz."""
    result = runner.invoke(app, ["fit", "--model", "mechanistic", "--data", "default",
                                 "--out", "/dev/null", "--json"])  # fmt: skip
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert out["model"] == "mechanistic" and out["split"]["train_rows"] == 21000
    assert out["split"]["mode"] == "chronological" and out["split"]["test_rows"] == 9000


def test_contradicting_and_meaningless_options_are_refused(belt: Path, tmp_path: Path) -> None:
    model = belt / "parallel.dtm"
    if not model.exists():
        pytest.skip("needs the model of test_hybrid_simulation_on_a_separate_test_record")
    test = ["--test-data", belt / "test.csv", "--mechanistic", belt / "sim_test.csv"]
    _refused(["evaluate", "--model", model, *test, "--outputs", "z"], "contradict", "--outputs z")
    _refused(["evaluate", "--model", model, *test, "--units", "y=m"], "y=m (model: y=rad/s)")
    _refused(["evaluate", "--model", model, *test, "--task", "prediction"], "fitted for 'simul")
    _refused(["predict", "--model", model, *test, "--init-samples", "30", "--out",
              tmp_path / "p.csv"], "--init-samples 30")  # fmt: skip
    _refused(["evaluate", "--model", model, "--test-data", belt / "test.csv"],
             "simulator output file(s)", "--mechanistic")  # fmt: skip
    fit = ["fit", "--data", belt / "train.csv", *CHANNELS, "--out", tmp_path / "x.dtm"]
    _refused([*fit, "--model", "parallel"], "needs the physics of the channels y", "config:")
    noted = runner.invoke(app, [str(a) for a in [  # the data description, noted not refused
        *fit[:-2], "--model", "persistence", "--inputs", "u", "--profile", "paper", "--epochs",
        "3", "--seed", "1", "--out", tmp_path / "persistence.dtm"]])  # fmt: skip
    assert noted.exit_code == 0, noted.output
    assert "--inputs u only describes the data" in noted.output
    assert "--profile, --seed, --epochs ignored" in noted.output
    _refused([*fit, "--model", "gru", "--inputs", "v"], "v")
    _refused([*fit, "--model", "gru", "--task", "simulation", "--horizon", "2"], "--horizon 2")
    _refused([*fit, "--model", "gru", "--test-data", belt / "test.csv", "--train-fraction",
              "0.5"], "--train-fraction")  # fmt: skip
    _refused(["fit", "--model", "gru", "--data", "default", "--outputs", "y", "--out",
              tmp_path / "d.dtm"], "--data default")  # fmt: skip
    _refused([*fit, "--model", "parallel", "--mechanistic", f"{belt / 'sim_test.csv'}"],
             "--mechanistic gives 1 simulator output table(s)", "sim_test.csv", "train.csv")  # fmt: skip
    assert not (tmp_path / "x.dtm").exists() and not (tmp_path / "p.csv").exists()
