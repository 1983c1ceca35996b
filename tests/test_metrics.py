"""Metrics against hand computations (SPEC section 3)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drafttwin.errors import DataError
from drafttwin.evaluation import evaluate, metrics_frame, persistence_forecast


def _one(y, yhat, **kw):
    return evaluate(
        np.array(y, float)[:, None], np.array(yhat, float)[:, None], rollers=("r",), **kw
    )["r"]


def test_relative_errors_by_hand() -> None:
    # errors 1, 2, 0 on 100, 200, 400 -> relative 1 %, 1 %, 0 %
    m = _one([100, 200, 400], [101, 198, 400])
    assert m.max_rel_err_pct == pytest.approx(1.0)
    assert m.mean_rel_err_pct == pytest.approx(2.0 / 3.0)
    assert m.accuracy_pct == pytest.approx(100 - 2.0 / 3.0)
    assert m.rmse_rpm == pytest.approx(math.sqrt((1 + 4 + 0) / 3))
    std = np.std([100, 200, 400])
    assert m.nrmse == pytest.approx(math.sqrt(5 / 3) / std)
    assert m.n_scored == 3 and m.n_nan_pred == 0 and m.n_excluded_low == 0
    assert math.isnan(m.skill) and math.isnan(m.noise_floor_rpm)


def test_low_speeds_are_excluded_and_counted() -> None:
    # |y| = 0.5 < 1 rpm: left out of relative errors (it would be 100 %), kept in RMSE
    m = _one([0.5, 100], [0.0, 103], min_abs_rpm=1.0)
    assert m.n_excluded_low == 1
    assert m.max_rel_err_pct == pytest.approx(3.0)
    assert m.mean_rel_err_pct == pytest.approx(3.0)
    assert m.rmse_rpm == pytest.approx(math.sqrt((0.25 + 9) / 2))


def test_nan_predictions_are_counted_not_scored() -> None:
    m = _one([100, 100, np.nan, 100], [np.nan, 102, 50, 99])
    assert m.n_nan_pred == 1  # row 0; row 2 has no measurement, so it is not counted
    assert m.n_scored == 2
    assert m.mean_rel_err_pct == pytest.approx(1.5)


def test_skill_against_persistence_by_hand() -> None:
    y = np.array([10.0, 12, 11, 13, 12])
    pers = persistence_forecast(y)
    np.testing.assert_array_equal(pers, [np.nan, 10, 12, 11, 13])
    yhat = np.array([np.nan, 11.0, 11.5, 12.0, 12.5])
    m = _one(y, yhat, persistence=pers)
    # rows 1..4: model errors -1, 0.5, -1, 0.5; persistence errors -2, 1, -2, 1
    rmse_model = math.sqrt((1 + 0.25 + 1 + 0.25) / 4)
    rmse_pers = math.sqrt((4 + 1 + 4 + 1) / 4)
    assert m.rmse_persistence_rpm == pytest.approx(rmse_pers)
    assert m.skill == pytest.approx(1 - rmse_model / rmse_pers)
    assert m.skill == pytest.approx(0.5)


def test_noise_floor_by_hand() -> None:
    y = np.array([100.0, 101, 99, np.nan])
    true = np.array([100.0, 100, 100, 100])
    m = _one(y, y, true_speed=true)
    assert m.noise_floor_rpm == pytest.approx(math.sqrt(2 / 3))
    assert m.rmse_rpm == 0.0


def test_per_roller_dict_and_frame() -> None:
    y = np.array([[1815.0, 435, 426, 355], [1816, 436, 425, 354]])
    out = evaluate(y, y + np.array([1.815, 0, 0, 0]))
    assert list(out) == ["front", "second", "third", "back"]
    assert out["front"].mean_rel_err_pct == pytest.approx(
        (100 * 1.815 / np.array([1815, 1816])).mean()
    )
    assert out["back"].max_rel_err_pct == 0.0
    frame = metrics_frame(out, model="gru")
    assert list(frame["roller"]) == ["front", "second", "third", "back"]
    assert frame["model"].unique().tolist() == ["gru"]
    assert {"rmse_rpm", "nrmse", "skill", "accuracy_pct", "n_excluded_low"} <= set(frame.columns)


def test_persistence_horizon_and_gaps() -> None:
    y = np.array([1.0, np.nan, 3.0, 4.0])
    np.testing.assert_array_equal(persistence_forecast(y, 1), [np.nan, 1, 1, 3])
    np.testing.assert_array_equal(persistence_forecast(y, 2), [np.nan, np.nan, 1, 1])
    with pytest.raises(ValueError):
        persistence_forecast(y, 0)


def test_shape_mismatch_is_refused() -> None:
    with pytest.raises(DataError, match="expected"):
        evaluate(np.zeros((3, 4)), np.zeros((3, 3)))
    with pytest.raises(DataError, match="rows"):
        evaluate(np.zeros((3, 4)), np.zeros((2, 4)))


def test_all_nan_gives_nan_metrics() -> None:
    m = _one([100.0, 100.0], [np.nan, np.nan])
    assert m.n_scored == 0 and m.n_nan_pred == 2
    assert math.isnan(m.rmse_rpm) and math.isnan(m.max_rel_err_pct)
