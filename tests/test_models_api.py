"""Estimator API: registry, profiles, settings objects, refusals at the boundary."""

from __future__ import annotations

import numpy as np
import pytest

from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import ConfigError, DataError
from drafttwin.models import (
    MDSL,
    MODEL_NAMES,
    PROFILES,
    GRUModel,
    LSTMModel,
    NotFittedError,
    Task,
    Training,
    make_model,
    persistence_forecast,
)

from ._synthetic import hyper_for


def test_registry_builds_every_name_under_every_profile() -> None:
    for profile in PROFILES:
        for name in MODEL_NAMES:
            model = make_model(name, profile=profile)
            assert model.name == name
    paper = make_model("md-s-l", profile="paper")
    assert (paper.hidden, paper.layers) == (256, 3)
    assert (paper.data_model.hidden, paper.data_model.layers) == (128, 3)
    tr = paper.training
    assert (tr.batch_size, tr.epochs, tr.lr, tr.patience, paper.dropout) == (
        10,
        500,
        1e-3,
        None,
        0.2,
    )
    assert paper.skip is False and make_model("md-s-l").skip is True
    assert make_model("md-s-l+d").use_disagreement is True


def test_flat_options_map_onto_the_settings_objects() -> None:
    model = make_model("md-s-l", epochs=3, lr=0.01, data_hidden=7, horizon=2, inputs=["u"])
    assert model.training.epochs == 3 and model.training.lr == 0.01
    assert model.data_model.hidden == 7 and model.data_model.training.epochs == 3
    assert model.task == Task(horizon=2, inputs=("u",))
    sim = make_model("parallel", task="simulation", init_samples=30)
    assert sim.task.simulation and sim.task.init_samples == 30
    assert sim.skip is None  # the profile's skip applies to one-step prediction only
    assert make_model("md-s-l", task="simulation").data_model.skip is None


def test_unknown_model_name_is_refused() -> None:
    with pytest.raises(ConfigError, match="unknown model 'transformer'") as err:
        make_model("transformer")
    assert "md-s-l" in str(err.value)


def test_unknown_profile_and_options_are_refused() -> None:
    with pytest.raises(ConfigError, match="unknown profile"):
        make_model("gru", profile="huge")
    with pytest.raises(ConfigError, match=r"\['kernel'\] do not apply to the gru model") as err:
        make_model("gru", kernel=5)
    assert "hidden" in str(err.value) and "epochs" in str(err.value)
    with pytest.raises(ConfigError, match=r"\['epochs', 'seed'\] do not apply to the mechanistic"):
        make_model("mechanistic", seed=1, epochs=3)
    with pytest.raises(ConfigError, match="data_hidden"):
        make_model("parallel", data_hidden=8)


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
        ("gru", {"lr": -1.0}, "lr"),
        ("gru", {"task": "forecast"}, "unknown task"),
    ],
)
def test_invalid_hyperparameters_are_refused(name, hyper, field, series, mech) -> None:
    with pytest.raises(ConfigError, match=field):
        make_model(name, **hyper_for(name, **hyper)).fit(series, mech)


def test_options_that_mean_nothing_for_the_task_are_refused(series, mech) -> None:
    with pytest.raises(ConfigError, match="accumulate=True does not apply .* task=prediction"):
        make_model("parallel", **hyper_for("parallel", accumulate=True)).fit(series, mech)
    gru = GRUModel(skip=True, task=Task("simulation"), training=Training(epochs=1))
    with pytest.raises(ConfigError, match="skip=True does not apply .* task=simulation"):
        gru.fit(series)
    with pytest.raises(ConfigError, match="init_samples=5 is only meaningful for a simulation"):
        Task(init_samples=5)
    with pytest.raises(ConfigError, match="horizon=2 is only meaningful"):
        Task("simulation", horizon=2)
    with pytest.raises(ConfigError, match="both inputs and outputs"):
        Task(outputs=("y",), inputs=("y",))
    with pytest.raises(ConfigError, match="takes no exogenous inputs"):
        make_model("persistence", inputs=("supply_hz",)).fit(series)
    with pytest.raises(ConfigError, match="val_fraction=0 leaves none"):  # the tail alone
        make_model(
            "parallel", task="simulation", val_fraction=0.0, val_folds=1, **hyper_for("parallel")
        ).fit(series, mech)


def test_simulation_window_longer_than_the_measured_start_is_refused(series, mech) -> None:
    model = make_model("gru", task="simulation", init_samples=4, **hyper_for("gru"))
    with pytest.raises(ConfigError, match="window=8 is longer than the 4 measured rows"):
        model.fit(series)


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_predict_before_fit_is_refused(name: str, series, mech) -> None:
    with pytest.raises(NotFittedError, match="not fitted") as err:
        make_model(name).predict_values(series, mech)
    assert err.value.exit_code == 2 and "fix: call fit(" in err.value.message


def test_channels_are_those_of_the_fit(series) -> None:
    three = MeasurementSeries(series.time_s, series.values[:, :3], channels=("a", "b", "c"))
    model = make_model("gru", **hyper_for("gru")).fit(three)
    assert model.channels_ == ("a", "b", "c")
    assert model.predict_values(three).shape == (len(three), 3)
    with pytest.raises(DataError, match=r"output channels \['front'.* fitted on \['a'"):
        model.predict_values(series)
    declared = make_model("persistence", outputs=("front", "second", "third", "back"))
    with pytest.raises(DataError, match="the model predicts"):
        declared.fit(three)


def test_missing_input_channel_is_named(series) -> None:
    model = make_model("gru", inputs=("u",), **hyper_for("gru"))
    with pytest.raises(DataError, match="no input channel 'u'"):
        model.fit(series)


def test_not_a_series_is_refused() -> None:
    with pytest.raises(DataError, match="MeasurementSeries"):
        make_model("gru").fit(np.zeros((100, 4)))  # type: ignore[arg-type]


def test_hybrid_without_mechanistic_is_refused(series) -> None:
    with pytest.raises(ConfigError, match="needs a mechanistic"):
        make_model("parallel", **hyper_for("parallel")).fit(series)


def test_too_short_training_part_is_refused(series, mech) -> None:
    with pytest.raises(DataError, match="too short"):
        make_model("md-s-l", **hyper_for("md-s-l")).fit(series.slice(0, 10), mech)
    with pytest.raises(DataError, match="training window"):
        make_model("gru", **hyper_for("gru")).fit(series.slice(0, 9))


def test_predictions_start_with_the_first_full_window(series) -> None:
    model = make_model("gru", **hyper_for("gru")).fit(series)  # window 8
    assert np.isnan(model.predict_values(series.slice(0, 8))).all()
    nine = model.predict_values(series.slice(0, 9))
    assert np.isnan(nine[:8]).all() and np.isfinite(nine[8]).all()
    np.testing.assert_allclose(nine[8], model.predict_values(series)[8], rtol=1e-9)  # batching


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


def test_persistence_and_windows_never_cross_a_record_boundary(series) -> None:
    two = MeasurementSeries.concat([series.slice(0, 100), series.slice(100)])
    pers = make_model("persistence").fit(two).predict_values(two)
    assert np.isnan(pers[100]).all() and np.isnan(pers[0]).all()
    np.testing.assert_array_equal(pers[101], two.values[100])
    gru = make_model("gru", **hyper_for("gru")).fit(two)
    pred = gru.predict_values(two)
    window = gru.window
    assert np.isnan(pred[100 : 100 + window]).all()  # a new record needs its own window
    assert np.isfinite(pred[100 + window :]).all() and np.isfinite(pred[window:100]).all()
    # the second record alone gives the same numbers: nothing leaks across the boundary
    np.testing.assert_allclose(pred[100:], gru.predict_values(two.slice(100)), atol=1e-6)


def test_get_and_set_params() -> None:
    model = make_model("gru", hidden=7)
    assert model.get_params()["hidden"] == 7
    assert model.set_params(hidden=9).hidden == 9
    with pytest.raises(ConfigError):
        model.set_params(nope=1)
    assert "hidden=9" in repr(model)


def test_mdsl_takes_its_data_model_as_an_object(series, mech) -> None:
    lstm = LSTMModel(window=6, hidden=5, layers=1, training=Training(epochs=1, device="cpu"))
    tiny = {k: v for k, v in hyper_for("md-s-l").items() if not k.startswith("data_")}
    model = make_model("md-s-l", data_model=lstm, **tiny)
    assert model.data_model.get_params() == {**lstm.get_params(), "training": lstm.training
                                             .replace(epochs=2, patience=2, batch_size=64)}  # fmt: skip
    model = MDSL(window=8, hidden=4, layers=1, sk_channels=6, folds=2, data_model=lstm,
                 training=Training(epochs=1, device="cpu"), quiet=True)  # fmt: skip
    assert model.data_model is lstm
    model.fit(series, mech)
    assert isinstance(model.data_model_, LSTMModel) and model.data_model_.hidden == 5
    assert model.data_model_.task == model.task
    with pytest.raises(ConfigError, match="data_model must be an unfitted GRUModel"):
        make_model("md-s-l", data_model="gru").fit(series, mech)
