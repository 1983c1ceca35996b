"""The library's side of the fit path (issue 27): a plant record's truth comes with
``read_measurements``, the time column keeps its name, and the protocol's published scoring
options (``skip_rows``, ``free_run_from``) are checked."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import drafttwin as dt
from drafttwin.errors import ConfigError
from drafttwin.evaluation import protocol


def _record(folder: Path, time_header: str = "t", n: int = 40) -> Path:
    t = np.arange(n) * 0.1
    path = folder / "rec.csv"
    pd.DataFrame({time_header: t, "y": 2.0 + 0.01 * np.arange(n)}).to_csv(path, index=False)
    return path


def test_read_measurements_attaches_the_plant_truth(tmp_path: Path) -> None:
    path = _record(tmp_path)
    n = 40
    truth = pd.DataFrame({"time": np.arange(n) * 0.1, "true_y": np.full(n, 2.5),
                          "missing_y": False, "outlier_y": np.arange(n) == 3})  # fmt: skip
    truth.to_csv(tmp_path / "rec.truth.csv", index=False)
    (tmp_path / "rec.json").write_text(json.dumps({"files": {"truth": "rec.truth.csv"}}))
    series = dt.read_measurements(path, outputs=["y"], inputs=())
    assert series.truth is not None and np.all(series.truth == 2.5)
    assert series.metadata["outlier_mask"][3, 0] and not series.metadata["missing_mask"].any()
    (tmp_path / "rec.json").write_text(json.dumps({"report": "drafttwin calibrate"}))
    assert dt.read_measurements(path, outputs=["y"], inputs=()).truth is None  # not a sidecar


@pytest.mark.parametrize(("header", "kept"), [("t", "t"), ("time_s", "time_s"),
                                              ("t [ms]", "time")])  # fmt: skip
def test_predictions_name_the_time_column_as_the_file_did(tmp_path, header, kept) -> None:
    series = dt.read_measurements(_record(tmp_path, header), outputs=["y"], inputs=())
    model = dt.make_model("persistence", outputs=("y",)).fit(series)
    assert model.predict(series).columns.tolist() == [kept, "y"]


def test_scoring_options_of_the_protocol(tmp_path: Path) -> None:
    series = dt.read_measurements(_record(tmp_path), outputs=["y"], inputs=())
    model = dt.make_model("persistence", outputs=("y",))
    part = dt.fit_split(model, series, train_fraction=0.5)
    whole = protocol.evaluate(model, part)
    later = protocol.evaluate(model, part, skip_rows=5)
    assert later.scored_rows == whole.scored_rows - 5 and later.split["score_from"] == 5
    with pytest.raises(ConfigError, match="free_run_from="):
        protocol.evaluate(model, part, free_run_from="start")  # one step ahead: no free run
    with pytest.raises(ConfigError, match="free_run_from="):
        protocol.evaluate(model, part, free_run_from="middle")


def test_fit_returns_the_fitted_model_and_fit_split_the_split(tmp_path: Path) -> None:
    series = dt.read_measurements(_record(tmp_path), outputs=["y"], inputs=())
    model = dt.make_model("persistence", outputs=("y",))
    assert dt.fit(model, series, train_fraction=0.5) is model  # as scikit-learn's fit
    other = dt.make_model("persistence", outputs=("y",))
    part = dt.fit_split(other, series, train_fraction=0.5)
    assert isinstance(part, protocol.Split) and part.train is not None
    assert model.provenance_["train_rows"] == other.provenance_["train_rows"] == len(part.train)
    a, b = dt.evaluate(model, part), dt.evaluate(other, part)
    assert a.metrics["y"].rmse == b.metrics["y"].rmse


def test_one_parser_names_the_physics_for_every_command(tmp_path: Path) -> None:
    from drafttwin.cli._common import load_train
    from drafttwin.diagnosis.physics import physics_train
    from drafttwin.models.mechanistic.source import PhysicsSource, parse_source
    from drafttwin.models.registry import drive_train

    toml = Path(__file__).resolve().parents[1] / "docs" / "examples" / "belt_drive.toml"
    assert parse_source("preset") == PhysicsSource("preset", "fa320a")
    assert parse_source("preset:fa320a") == PhysicsSource("preset", "fa320a")
    assert parse_source(f"config:{toml}") == PhysicsSource("config", paths=(toml,))
    assert parse_source("a.csv, b.csv").paths == (Path("a.csv"), Path("b.csv"))
    with pytest.raises(ConfigError, match="config: needs a file"):
        parse_source("config:")
    # The option the user typed, not mechanics' own --preset.
    with pytest.raises(ConfigError, match=r"^--model: unknown preset 'bogus'.*preset:fa320a"):
        parse_source("preset:bogus", where="--model")
    belt = drive_train(f"config:{toml}").to_dict()
    assert physics_train(f"config:{toml}").to_dict() == belt == load_train(None, toml).to_dict()
    model = dt.make_model("mechanistic", outputs=("y",))
    series = dt.read_measurements(_record(tmp_path), outputs=["y"], inputs=())
    model.fit(series, dt.MechanisticModel.from_option("preset"))  # records its source only
    path = tmp_path / "m.dtm"
    model.save(path)
    assert physics_train(str(path)).to_dict() == load_train("fa320a", None).to_dict()
