"""Estimator API: registry, profiles, refusals at the boundary, mechanistic sources."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import ConfigError, DataError, DrafttwinError
from drafttwin.evaluation import persistence_forecast
from drafttwin.models import (
    MDSL,
    MODEL_NAMES,
    PROFILES,
    GRUModel,
    MechanisticModel,
    NotFittedError,
    make_model,
)

from ._synthetic import hyper_for, make_series, mechanistic, one_thread


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    with one_thread():
        yield


@pytest.fixture(scope="module")
def series() -> MeasurementSeries:
    return make_series(200, seed=3)[0]


def test_registry_builds_every_name_under_every_profile() -> None:
    for profile in PROFILES:
        for name in MODEL_NAMES:
            model = make_model(name, profile=profile)
            assert model.name == name
    paper = make_model("md-s-l", profile="paper")
    assert (paper.hidden, paper.layers, paper.data_hidden, paper.data_layers) == (256, 3, 128, 3)
    assert (paper.batch_size, paper.epochs, paper.lr, paper.dropout) == (10, 500, 1e-3, 0.2)
    assert make_model("md-s-l+d").use_disagreement is True


def test_unknown_model_name_is_refused() -> None:
    with pytest.raises(ConfigError, match="unknown model 'transformer'") as err:
        make_model("transformer")
    assert "md-s-l" in str(err.value)


def test_unknown_profile_and_hyperparameter_are_refused() -> None:
    with pytest.raises(ConfigError, match="unknown profile"):
        make_model("gru", profile="huge")
    with pytest.raises(ConfigError, match="unknown hyperparameter"):
        make_model("gru", kernel=5)


@pytest.mark.parametrize(
    ("name", "hyper", "field"),
    [
        ("gru", {"window": 0}, "window"),
        ("gru", {"dropout": 1.5}, "dropout"),
        ("gru", {"horizon": 0}, "horizon"),
        ("md-s-l", {"sk_channels": 10}, "sk_channels"),
        ("md-s-l", {"folds": 1}, "folds"),
        ("md-s-l", {"variant": "md-x"}, "variant"),
        ("lstm", {"device": "tpu-9"}, "device"),
    ],
)
def test_invalid_hyperparameters_are_refused_at_fit(name, hyper, field, series) -> None:
    model = make_model(name, **hyper_for(name, **hyper))
    with pytest.raises(ConfigError, match=field):
        model.fit(series, MechanisticModel(mechanistic))


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_predict_before_fit_is_refused(name: str, series) -> None:
    with pytest.raises(NotFittedError, match="not fitted"):
        make_model(name).predict_values(series, MechanisticModel(mechanistic))


def test_wrong_roller_count_is_refused(series) -> None:
    three = MeasurementSeries(
        series.time_s, series.values[:, :3], channels=("front", "second", "third")
    )
    with pytest.raises(DataError, match="3 roller column"):
        make_model("gru", **hyper_for("gru")).fit(three)
    fitted = make_model("persistence").fit(series)
    with pytest.raises(DataError, match="3 roller column"):
        fitted.predict_values(three)


def test_other_roller_names_are_refused_at_predict(series) -> None:
    fitted = make_model("persistence").fit(series)
    renamed = MeasurementSeries(series.time_s, series.values, channels=("a", "b", "c", "d"))
    with pytest.raises(DataError, match="fitted on"):
        fitted.predict_values(renamed)


def test_not_a_series_is_refused() -> None:
    with pytest.raises(DataError, match="MeasurementSeries"):
        make_model("gru").fit(np.zeros((100, 4)))  # type: ignore[arg-type]


def test_hybrid_without_mechanistic_is_refused(series) -> None:
    with pytest.raises(ConfigError, match="needs a mechanistic"):
        make_model("parallel", **hyper_for("parallel")).fit(series)


def test_too_short_training_part_is_refused(series) -> None:
    with pytest.raises(DataError, match="too short"):
        MDSL(**hyper_for("md-s-l")).fit(series.slice(0, 10), MechanisticModel(mechanistic))
    with pytest.raises(DataError, match="training window"):
        GRUModel(**hyper_for("gru")).fit(series.slice(0, 9))


def test_predict_on_a_short_series_is_all_nan(series) -> None:
    model = GRUModel(**hyper_for("gru")).fit(series)
    assert np.isnan(model.predict_values(series.slice(0, 8))).all()


def test_persistence_model_is_the_last_observation(series) -> None:
    rpm = series.values.copy()
    rpm[50, 1] = np.nan
    s = series.with_values(rpm)
    for h in (1, 3):
        pred = make_model("persistence", horizon=h).fit(s).predict_values(s)
        np.testing.assert_array_equal(pred, persistence_forecast(rpm, h))
        np.testing.assert_array_equal(pred[h:, 0], rpm[:-h, 0])
    pred = make_model("persistence").fit(s).predict_values(s)
    assert pred[51, 1] == rpm[49, 1]  # missing y_50 -> carry y_49 forward


def test_get_and_set_params() -> None:
    model = make_model("gru", hidden=7)
    assert model.get_params()["hidden"] == 7
    assert model.set_params(hidden=9).hidden == 9
    with pytest.raises(ConfigError):
        model.set_params(nope=1)
    assert "hidden=9" in repr(model)


def test_errors_are_drafttwin_errors() -> None:
    assert issubclass(NotFittedError, DrafttwinError)


# ----- mechanistic sources ---------------------------------------------------------------
def _sim_frame(time_s: np.ndarray) -> pd.DataFrame:
    mech = mechanistic(time_s)
    return pd.DataFrame({"time": time_s, **{r: mech[:, j] for j, r in enumerate(
        ("front", "second", "third", "back"))}})  # fmt: skip


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_file_source_is_interpolated_onto_the_grid(suffix: str, series, tmp_path: Path) -> None:
    coarse = np.arange(0, series.time_s[-1] + 0.05, 0.05)
    frame = _sim_frame(coarse)
    path = tmp_path / f"sim{suffix}"
    frame.to_parquet(path) if suffix == ".parquet" else frame.to_csv(path, index=False)
    got = MechanisticModel(path).predict(series)
    want = np.column_stack(
        [np.interp(series.time_s, coarse, frame[r]) for r in ("front", "second", "third", "back")]
    )
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)


def test_file_source_not_covering_the_span_is_refused(series, tmp_path: Path) -> None:
    path = tmp_path / "short.csv"
    _sim_frame(np.arange(0, 1.0, 0.01)).to_csv(path, index=False)
    with pytest.raises(DataError, match="covers 0 s to 0.99 s") as err:
        MechanisticModel(path).predict(series)
    assert str(path) in str(err.value)


def test_file_source_problems_are_named(tmp_path: Path) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("time,front,second,third,back\n0,1,2,3,4\n0.01,1,x,3,4\n")
    with pytest.raises(DataError, match="column 'second'"):
        MechanisticModel(bad)
    back = tmp_path / "back.csv"
    back.write_text("time,front,second,third,back\n0,1,2,3,4\n0,1,2,3,4\n")
    with pytest.raises(DataError, match="not strictly increasing"):
        MechanisticModel(back)
    no_time = tmp_path / "nt.csv"
    no_time.write_text("front,second,third,back\n1,2,3,4\n1,2,3,4\n")
    with pytest.raises(DataError, match="no time column"):
        MechanisticModel(no_time)
    with pytest.raises(DataError, match="file not found"):
        MechanisticModel(tmp_path / "missing.csv")


def test_column_mapping(series, tmp_path: Path) -> None:
    frame = _sim_frame(series.time_s).rename(columns={"front": "v1", "back": "v4"})
    model = MechanisticModel(frame, columns={"front": "v1", "back": "v4"})
    np.testing.assert_allclose(model.predict(series), mechanistic(series.time_s), atol=1e-9)


def test_array_and_callable_sources_are_checked(series) -> None:
    arr = mechanistic(series.time_s)
    np.testing.assert_array_equal(MechanisticModel(arr).predict(series), arr)
    with pytest.raises(DataError, match="rows but the series has"):
        MechanisticModel(arr[:-1]).predict(series)
    with pytest.raises(DataError, match="shape"):
        MechanisticModel(lambda t: np.zeros((len(t), 3))).predict(series)
    with pytest.raises(DataError, match="finite"):
        MechanisticModel(lambda t: np.full((len(t), 4), np.nan)).predict(series)
    with pytest.raises(DataError, match="cannot use"):
        MechanisticModel(42)  # type: ignore[arg-type]
