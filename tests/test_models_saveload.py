"""One-file save/load: identical predictions after reload; clear refusals of bad files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from drafttwin.errors import ModelFileError
from drafttwin.models import (
    FORMAT_VERSION,
    MDSL,
    GRUModel,
    MechanisticModel,
    load_model,
    make_model,
)

from ._synthetic import hyper_for, make_series, mechanistic, one_thread

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


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    with one_thread():
        yield


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
    assert loaded.get_params() == model.get_params()
    assert loaded.name == model.name
    np.testing.assert_array_equal(loaded.predict_values(series, mech), model.predict_values(series, mech))
    if hasattr(model, "history_"):
        assert loaded.history_.train_loss == model.history_.train_loss


def test_class_load_and_file_contents(gru_file: Path, series) -> None:
    model = GRUModel.load(gru_file)
    assert model.rollers_ == series.channels
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
    payload["params"]["hidden"] = 5  # the stored tensors no longer fit
    path = tmp_path / "bad.pt"
    torch.save(payload, path)
    with pytest.raises(ModelFileError, match="damaged or inconsistent"):
        load_model(path)


def test_save_is_atomic_and_refuses_unfitted(tmp_path: Path) -> None:
    from drafttwin.models import NotFittedError

    with pytest.raises(NotFittedError):
        make_model("gru").save(tmp_path / "x.pt")
    assert list(tmp_path.iterdir()) == []


def test_saved_preset_or_file_source_is_reused(series, tmp_path: Path) -> None:
    """A file-based mechanistic source is recorded in the model and reused by predict."""
    frame = series.to_frame()[["time"]].copy()
    mech = mechanistic(series.time_s)
    for j, name in enumerate(series.channels):
        frame[name] = mech[:, j]
    csv = tmp_path / "sim.csv"
    frame.to_csv(csv, index=False)
    model = make_model("parallel", **hyper_for("parallel")).fit(series, MechanisticModel(csv))
    loaded = load_model(model.save(tmp_path / "p.pt"))
    np.testing.assert_array_equal(loaded.predict_values(series), model.predict_values(series, csv))
