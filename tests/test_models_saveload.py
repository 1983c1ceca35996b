"""One-file save/load: identical predictions after reload; clear refusals of bad files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from drafttwin.errors import ConfigError, ModelFileError
from drafttwin.models import (
    FORMAT_VERSION,
    MDSL,
    GRUModel,
    MechanisticModel,
    load_model,
    make_model,
)
from drafttwin.models.estimators.params import encode_params

from ._synthetic import hyper_for, make_series, mechanistic

BELT = Path(__file__).resolve().parents[1] / "docs" / "examples" / "belt_drive.toml"

ALL = [
    "mechanistic",
    "persistence",
    "gru",
    "lstm",
    "parallel",
    "md-s-l",
    "md-l",
    "md-s",
    "md-s-l+d",
]


@pytest.fixture(scope="module")
def series():
    return make_series(300, seed=2)[0]


@pytest.fixture(scope="module")
def gru_file(tmp_path_factory: pytest.TempPathFactory, series) -> Path:
    path = tmp_path_factory.mktemp("models") / "gru.pt"
    make_model("gru", **hyper_for("gru")).fit(series).save(path)
    return path


@pytest.mark.parametrize("name", ALL)
def test_round_trip_gives_identical_predictions(name: str, series, tmp_path: Path) -> None:
    mech = MechanisticModel(mechanistic)
    model = make_model(name, **hyper_for(name)).fit(series.slice(0, 220), mech)
    path = model.save(tmp_path / "m.pt")
    loaded = load_model(path)
    assert type(loaded) is type(model)
    assert encode_params(loaded.get_params()) == encode_params(model.get_params())
    assert loaded.name == model.name
    np.testing.assert_array_equal(
        loaded.predict_values(series, mech), model.predict_values(series, mech)
    )
    if hasattr(model, "history_"):
        assert loaded.history_.train_loss == model.history_.train_loss


def test_class_load_and_file_contents(gru_file: Path, series) -> None:
    model = GRUModel.load(gru_file)
    assert model.channels_ == series.channels
    assert model.units_ == {c: "rpm" for c in series.channels}
    payload = torch.load(gru_file, weights_only=True)
    assert payload["format"] == "drafttwin-model"
    assert payload["format_version"] == FORMAT_VERSION
    assert payload["model_class"] == "GRUModel"
    assert "drafttwin_version" in payload
    assert all(isinstance(v, torch.Tensor) for v in payload["tensors"].values())


def test_refuses_loading_as_another_class(gru_file: Path) -> None:
    with pytest.raises(ModelFileError, match="holds a GRUModel, not a MDSL"):
        MDSL.load(gru_file)


def test_refuses_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ModelFileError, match="file not found"):
        load_model(tmp_path / "nope.pt")


def test_refuses_a_text_file(tmp_path: Path) -> None:
    path = tmp_path / "notes.pt"
    path.write_text("time,front\n0,1815\n")
    with pytest.raises(ModelFileError, match="not a readable drafttwin model") as err:
        load_model(path)
    assert str(path) in str(err.value) and "fix:" in str(err.value)


def test_refuses_a_foreign_torch_file(tmp_path: Path) -> None:
    path = tmp_path / "foreign.pt"
    torch.save({"weight": torch.zeros(3)}, path)
    with pytest.raises(ModelFileError, match="not a drafttwin model"):
        load_model(path)


def test_refuses_a_pickled_object_without_unpickling_it(tmp_path: Path) -> None:
    path = tmp_path / "evil.pt"
    torch.save({"format": "drafttwin-model", "obj": Path("x")}, path)
    with pytest.raises(ModelFileError, match="not a readable"):
        load_model(path)


def test_refuses_another_format_version(gru_file: Path, tmp_path: Path) -> None:
    payload = torch.load(gru_file, weights_only=True)
    payload["format_version"] = FORMAT_VERSION + 1
    path = tmp_path / "future.pt"
    torch.save(payload, path)
    with pytest.raises(ModelFileError, match=f"format version {FORMAT_VERSION + 1}"):
        load_model(path)


def test_refuses_a_truncated_file(gru_file: Path, tmp_path: Path) -> None:
    path = tmp_path / "cut.pt"
    path.write_bytes(gru_file.read_bytes()[:400])
    with pytest.raises(ModelFileError):
        load_model(path)


def test_refuses_inconsistent_weights(gru_file: Path, tmp_path: Path) -> None:
    payload = torch.load(gru_file, weights_only=True)
    params = json.loads(payload["params_json"])
    payload["params_json"] = json.dumps({**params, "hidden": 5})  # tensors no longer fit
    path = tmp_path / "bad.pt"
    torch.save(payload, path)
    with pytest.raises(ModelFileError, match="damaged or inconsistent"):
        load_model(path)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"window": 0}, "window=0 is invalid"),
        ({"training": {"__training__": {"epochs": 0}}}, "training setting epochs=0"),
        ({"task": {"__task__": {"kind": "prediction", "horizon": 0}}}, "horizon=0"),
        ({"task": {"__model__": "Evil", "params": {}}}, "unknown estimator class 'Evil'"),
    ],
)
def test_refuses_invalid_hyperparameters_on_load(gru_file, tmp_path, change, match) -> None:
    """Model files are validated on load as on save: a hand-edited file is refused."""
    payload = torch.load(gru_file, weights_only=True)
    payload["params_json"] = json.dumps({**json.loads(payload["params_json"]), **change})
    path = tmp_path / "edited.pt"
    torch.save(payload, path)
    with pytest.raises(ModelFileError, match=match):
        load_model(path)


def test_save_is_atomic_and_refuses_unfitted(tmp_path: Path) -> None:
    from drafttwin.models import NotFittedError

    with pytest.raises(NotFittedError):
        make_model("gru").save(tmp_path / "x.pt")
    assert list(tmp_path.iterdir()) == []


def test_a_file_source_is_named_but_never_read_back_from_the_model(series, tmp_path) -> None:
    """A model file names the simulator output it was fitted with but never makes predict
    read a path recorded in it: the user passes the source again."""
    frame = series.to_frame()[["time"]].copy()
    mech = mechanistic(series.time_s)
    for j, name in enumerate(series.channels):
        frame[name] = mech[:, j]
    csv = tmp_path / "sim.csv"
    frame.to_csv(csv, index=False)
    model = make_model("parallel", **hyper_for("parallel")).fit(series, MechanisticModel(csv))
    loaded = load_model(model.save(tmp_path / "p.pt"))
    with pytest.raises(ConfigError, match=r"fitted with the simulator output file\(s\) .*sim.csv"):
        loaded.predict_values(series)
    np.testing.assert_array_equal(loaded.predict_values(series, MechanisticModel(csv)),
                                  model.predict_values(series, MechanisticModel(csv)))  # fmt: skip


def test_a_drive_train_source_is_stored_whole(tmp_path) -> None:
    """A drive train (the user's TOML) is kept in the model file: predict needs no file."""
    from drafttwin.data.series import MeasurementSeries
    from drafttwin.mechanics import DriveTrain

    toml = tmp_path / "train.toml"
    toml.write_text(BELT.read_text())
    train = DriveTrain.from_toml(toml)
    t = np.arange(1, 301) * 0.01
    u = np.where(t < 1.0, 6.0, 8.0)
    physics = MechanisticModel.from_train(train)
    truth = physics.predict_values(
        MeasurementSeries(t, np.zeros(300), channels=("y",), inputs={"u": u})
    )
    y = truth[:, 0] * 1.01
    data = MeasurementSeries(t, y, channels=("y",), units={"y": "rad/s"}, inputs={"u": u})
    model = make_model("mechanistic").fit(data, MechanisticModel.from_config(toml))
    toml.unlink()  # the file is gone; the model holds the train
    loaded = load_model(model.save(tmp_path / "m.pt"))
    np.testing.assert_array_equal(loaded.predict_values(data), truth)
