"""Streaming prediction equals batch prediction and follows the same protocol."""

from __future__ import annotations

import numpy as np
import pytest

from drafttwin.errors import DataError
from drafttwin.models import MechanisticModel, OnlinePredictor, make_model

from ._synthetic import hyper_for, make_series, mechanistic

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
    return make_series(300, seed=5, missing=0.02)[0]


@pytest.mark.parametrize("horizon", [1, 2])
@pytest.mark.parametrize("name", ALL)
def test_online_steps_match_batch_predict(name: str, horizon: int, series) -> None:
    mech = MechanisticModel(mechanistic)
    extra = {} if name == "mechanistic" else {"horizon": horizon}
    model = make_model(name, **hyper_for(name, **extra)).fit(series.slice(0, 200), mech)
    batch = model.predict_values(series, mech)
    h = 1 if name == "mechanistic" else horizon
    online = OnlinePredictor(model, mech)
    online.observe_series(series.slice(0, 150))  # warm start, then step
    steps = []
    for i in range(150, len(series) - h + 1):
        steps.append(online.forecast(float(series.time_s[i + h - 1])))
        online.observe(float(series.time_s[i]), series.values[i])
    got = np.array(steps)
    want = batch[150 + h - 1 :]
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-3, equal_nan=True)


def test_online_from_scratch_matches_and_starts_with_nan(series) -> None:
    mech = MechanisticModel(mechanistic)
    model = make_model("md-s-l+d", **hyper_for("md-s-l+d")).fit(series.slice(0, 200), mech)
    batch = model.predict_values(series.slice(0, 80), mech)
    online = OnlinePredictor(model, mech)
    got = []
    for i in range(80):
        got.append(online.forecast(float(series.time_s[i])))
        online.observe(float(series.time_s[i]), series.values[i])
    np.testing.assert_allclose(np.array(got), batch, rtol=0, atol=1e-3, equal_nan=True)
    assert np.isnan(got[0]).all() and np.isfinite(got[-1]).all()


def test_online_refuses_bad_rows(series) -> None:
    online = OnlinePredictor(make_model("persistence").fit(series))
    with pytest.raises(
        DataError, match=r"a row needs 4 values \(front, second, third, back\), got 3"
    ):
        online.observe(0.0, [1.0, 2.0, 3.0])


def test_online_refuses_row_aligned_mechanistic_arrays(series) -> None:
    from drafttwin.errors import ConfigError

    mech = MechanisticModel(mechanistic)
    model = make_model("parallel", **hyper_for("parallel")).fit(series, mech)
    with pytest.raises(ConfigError, match="one time stamp at a time"):
        OnlinePredictor(model, MechanisticModel(mechanistic(series.time_s)))


def test_online_with_the_callers_mechanistic_rows_equals_asking_the_source(series) -> None:
    """The live twin hands the physics row it stepped itself: same forecasts bit for bit;
    a row of the wrong shape or not finite is refused."""
    mech = MechanisticModel(mechanistic)
    model = make_model("md-s-l+d", **hyper_for("md-s-l+d")).fit(series.slice(0, 200), mech)
    asked, given = OnlinePredictor(model, mech), OnlinePredictor(model, mech)
    rows = mech.values_at(series.time_s, model.channels_)
    for i in range(120):
        t = float(series.time_s[i])
        np.testing.assert_array_equal(asked.forecast(t), given.forecast(t, rows[i]))
        asked.observe(t, series.values[i])
        given.observe(t, series.values[i], rows[i])
    with pytest.raises(DataError, match="is not 4 finite values"):
        given.observe(1.0, series.values[0], rows[0][:3])
    with pytest.raises(DataError, match="is not 4 finite values"):
        given.forecast(1.0, np.full(4, np.nan))
