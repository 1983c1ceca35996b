"""Metrics against hand and NumPy computations, for roller speeds and for any signal."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from drafttwin.errors import ConfigError, DataError
from drafttwin.evaluation import ChannelMetrics, channel_metrics, metrics_frame
from drafttwin.evaluation.metrics import NOTE_ALL_LOW, NOTE_CROSSES_ZERO, NOTE_ZERO
from drafttwin.models import persistence_forecast


def _one(y, yhat, **kw) -> ChannelMetrics:
    return channel_metrics(np.array(y, float), np.array(yhat, float), channels=("r",), **kw)["r"]


def test_relative_errors_by_hand() -> None:
    # errors 1, 2, 0 on 100, 200, 400 -> relative 1 %, 1 %, 0 %
    m = _one([100, 200, 400], [101, 198, 400], units="rpm")
    assert m.channel == "r" and m.unit == "rpm"
    assert m.max_rel_err_pct == pytest.approx(1.0)
    assert m.mean_rel_err_pct == pytest.approx(2.0 / 3.0)
    assert m.accuracy_pct == pytest.approx(100 - 2.0 / 3.0)
    assert m.rmse == pytest.approx(math.sqrt((1 + 4 + 0) / 3))
    assert m.bias == pytest.approx((1 - 2 + 0) / 3)  # mean error, prediction minus measurement
    std = np.std([100, 200, 400])
    assert m.nrmse == pytest.approx(math.sqrt(5 / 3) / std)
    assert m.n_scored == 3 and m.n_nan_pred == 0 and m.n_rel_excluded == 0
    assert m.rel_note is None
    # scale = 99th percentile of |y| (linear interpolation): 200 + 0.98 * 200 = 396
    assert m.rel_threshold == pytest.approx(0.01 * 396.0)
    assert math.isnan(m.skill) and math.isnan(m.sensor_rmse) and math.isnan(m.rmse_floor)
    assert math.isnan(m.rmse_vs_true) and math.isnan(m.true_error_ratio)


def test_undeclared_unit_is_empty() -> None:
    assert _one([1.0, 2.0], [1.0, 2.0]).unit == ""


def test_startup_ramp_from_zero_excludes_and_counts_low_samples() -> None:
    # a start-up ramp 0 -> 1800 rpm over 100 samples, then 900 samples of steady running
    y = np.concatenate([np.linspace(0.0, 1800.0, 100), np.full(900, 1800.0)])
    yhat = y + 2.0
    m = _one(y, yhat, units="rpm")
    # scale: >= 99 % of the samples are at 1800 rpm, so the threshold is 18 rpm; the ramp
    # step is 1800 / 99 rpm, so the samples 0, 18.18... are the ones below it: only sample 0
    threshold = 0.01 * np.percentile(np.abs(y), 99)
    assert threshold == pytest.approx(18.0)
    expected_low = int((np.abs(y) < threshold).sum())
    assert expected_low == 1
    assert m.rel_threshold == pytest.approx(18.0)
    assert m.n_rel_excluded == expected_low
    kept = y[y >= threshold]
    rel = 100 * 2.0 / kept
    assert m.max_rel_err_pct == pytest.approx(rel.max())
    assert m.mean_rel_err_pct == pytest.approx(rel.mean())
    assert m.rmse == pytest.approx(2.0)  # the excluded sample stays in the RMSE
    # a slower start-up: 300 ramp samples, of which those under 18 rpm are excluded
    y2 = np.concatenate([np.linspace(0.0, 1800.0, 300), np.full(2000, 1800.0)])
    m2 = _one(y2, y2 * 1.001)
    low2 = np.abs(y2) < 18.0
    assert m2.n_rel_excluded == int(low2.sum()) == 3  # 0, 6.02, 12.04 rpm
    assert m2.mean_rel_err_pct == pytest.approx(0.1)
    assert m2.n_scored == y2.size


def test_steady_rollers_exclude_nothing() -> None:
    rng = np.random.default_rng(3)
    mean = np.array([1813.0, 434.0, 426.0, 355.0])
    y = mean + 0.5 * rng.standard_normal((2000, 4))
    out = channel_metrics(y, y + 0.3, units="rpm")
    for j, r in enumerate(("front", "second", "third", "back")):
        assert out[r].n_rel_excluded == 0 and out[r].rel_note is None
        assert out[r].rel_threshold == pytest.approx(0.01 * np.percentile(y[:, j], 99))
        assert out[r].mean_rel_err_pct == pytest.approx(np.mean(100 * 0.3 / y[:, j]))


def test_zero_crossing_sine_omits_relative_errors() -> None:
    t = np.arange(2000) / 100.0
    y = 0.25 * np.sin(2 * np.pi * 0.5 * t)  # a position in m
    err = 0.003 * np.cos(2 * np.pi * 7.0 * t)
    m = _one(y, y + err, units="m", persistence=persistence_forecast(y))
    assert m.rel_note == NOTE_CROSSES_ZERO
    assert math.isnan(m.max_rel_err_pct) and math.isnan(m.mean_rel_err_pct)
    assert math.isnan(m.accuracy_pct)
    assert m.rmse == pytest.approx(np.sqrt(np.mean(err**2)), rel=1e-12)
    assert m.rmse == pytest.approx(0.003 / math.sqrt(2), rel=1e-3)
    assert m.nrmse == pytest.approx(m.rmse / np.std(y), rel=1e-12)
    pers = persistence_forecast(y)[1:] - y[1:]
    expected_skill = 1 - np.sqrt(np.mean(err[1:] ** 2)) / np.sqrt(np.mean(pers**2))
    assert m.skill == pytest.approx(expected_skill, rel=1e-12)
    assert m.rel_threshold == pytest.approx(0.01 * np.percentile(np.abs(y), 99))


def test_noise_about_zero_during_a_stop_is_not_a_crossing() -> None:
    # running at 400 rpm, then 10 % of the time stopped with +-0.6 rpm encoder noise
    rng = np.random.default_rng(0)
    y = np.concatenate([np.full(900, 400.0), 0.6 * rng.choice([-1.0, 0.0, 1.0], 100)])
    m = _one(y, y + 1.0)
    assert m.rel_note is None
    assert m.n_rel_excluded == 100  # all stop samples lie under 4 rpm (or are 0)
    assert m.mean_rel_err_pct == pytest.approx(0.25)


def test_a_few_negative_samples_are_not_a_crossing() -> None:
    # 0.5 % of the samples clearly negative: below the negligible share (1 %)
    y = np.concatenate([np.full(995, 10.0), np.full(5, -10.0)])
    m = _one(y, y * 1.02)
    assert m.rel_note is None and m.mean_rel_err_pct == pytest.approx(2.0)
    y2 = np.concatenate([np.full(970, 10.0), np.full(30, -10.0)])  # 3 %: crosses zero
    assert _one(y2, y2 * 1.02).rel_note == NOTE_CROSSES_ZERO


def test_zero_signal_and_all_low_samples_have_notes() -> None:
    m = _one([0.0, 0.0, 0.0], [0.1, -0.1, 0.0])
    assert m.rel_note == NOTE_ZERO and math.isnan(m.mean_rel_err_pct)
    assert m.rmse == pytest.approx(math.sqrt(0.02 / 3))
    # the large samples have no prediction: every scored one lies below the threshold
    y = np.concatenate([np.full(10, 0.001), np.full(990, 100.0)])
    yhat = np.concatenate([np.full(10, 0.002), np.full(990, np.nan)])
    m2 = _one(y, yhat)
    assert m2.rel_note == NOTE_ALL_LOW and m2.n_rel_excluded == 10 and m2.n_nan_pred == 990
    assert math.isnan(m2.max_rel_err_pct) and m2.rmse == pytest.approx(0.001)


def test_rel_floor_zero_keeps_every_nonzero_sample_and_bad_floor_is_refused() -> None:
    m = _one([0.5, 100], [0.0, 103], rel_floor=0.0)
    assert m.n_rel_excluded == 0 and m.rel_threshold == 0.0
    assert m.max_rel_err_pct == pytest.approx(100.0)
    assert m.mean_rel_err_pct == pytest.approx((100.0 + 3.0) / 2)
    m2 = _one([0.5, 100], [0.0, 103])  # default floor: 0.5 is under 1 % of ~99.5
    assert m2.n_rel_excluded == 1 and m2.mean_rel_err_pct == pytest.approx(3.0)
    assert m2.rmse == pytest.approx(math.sqrt((0.25 + 9) / 2))
    with pytest.raises(ConfigError, match=r"rel_floor must be in \[0, 1\), got 1.5"):
        _one([1.0], [1.0], rel_floor=1.5)


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
    assert m.rmse_persistence == pytest.approx(rmse_pers)
    assert m.skill == pytest.approx(1 - rmse_model / rmse_pers)
    assert m.skill == pytest.approx(0.5)


def test_limits_against_the_true_value_by_hand() -> None:
    y = np.array([100.0, 101, 99, np.nan, 102])
    true = np.array([100.0, 100, 100, 100, 100])
    pred = np.array([100.5, 100.0, 100.0, 100.0, np.nan])  # the last one is not scored
    oracle = np.array([100.0, 100.5, 100.0, 100.0, 101.0])
    m = _one(y, pred, true_values=true, floor_values=oracle)
    # on the three scored samples only (measured and predicted)
    assert m.sensor_rmse == pytest.approx(math.sqrt(2 / 3))
    assert m.rmse_vs_true == pytest.approx(math.sqrt(0.25 / 3))
    assert m.true_error_ratio == pytest.approx(math.sqrt(0.25 / 2))
    assert m.rmse_floor == pytest.approx(math.sqrt((0 + 0.25 + 1) / 3))
    assert m.rmse == pytest.approx(math.sqrt((0.25 + 1 + 1) / 3))


def test_many_channels_dict_and_frame() -> None:
    y = np.array([[1815.0, 435, 426, 355], [1816, 436, 425, 354]])
    out = channel_metrics(y, y + np.array([1.815, 0, 0, 0]), units="rpm")
    assert list(out) == ["front", "second", "third", "back"]
    assert out["front"].mean_rel_err_pct == pytest.approx(
        (100 * 1.815 / np.array([1815, 1816])).mean()
    )
    assert out["back"].max_rel_err_pct == 0.0
    frame = metrics_frame(out, model="gru")
    assert list(frame["channel"]) == ["front", "second", "third", "back"]
    assert frame["model"].unique().tolist() == ["gru"]
    expected = {"rmse", "nrmse", "skill", "accuracy_pct", "n_rel_excluded", "unit", "rel_note"}
    assert expected <= set(frame.columns)
    assert frame["skill"].isna().all()  # NaN, not None, in the frame


def test_channels_with_their_own_units() -> None:
    y = np.column_stack([np.linspace(0.1, 0.2, 50), np.full(50, 12.0), np.full(50, 3.0)])
    yhat = y + np.array([0.001, 0.5, -0.3])
    units = {"position": "m", "voltage": "V", "supply_hz": "Hz"}  # extra names are ignored
    out = channel_metrics(y, yhat, channels=("position", "voltage", "level"), units=units)
    assert [m.unit for m in out.values()] == ["m", "V", ""]
    assert out["position"].rmse == pytest.approx(0.001)
    assert out["voltage"].mean_rel_err_pct == pytest.approx(100 * 0.5 / 12)
    assert out["level"].max_rel_err_pct == pytest.approx(10.0)
    listed = channel_metrics(y, yhat, channels=("a", "b", "c"), units=["m", "V", "cm"])
    assert [m.unit for m in listed.values()] == ["m", "V", "cm"]
    three = r"3 channels were named \(a, b, c\)"
    with pytest.raises(DataError, match=rf"2 units were given but {three}"):
        channel_metrics(y, yhat, channels=("a", "b", "c"), units=["m", "V"])


def test_json_round_trip_without_nan() -> None:
    t = np.arange(500) / 100.0
    y = np.sin(2 * np.pi * t)
    yhat = y + 0.01
    yhat[:10] = np.nan
    out = channel_metrics(y, yhat, channels=("x",), units="m")
    text = json.dumps({k: m.to_dict() for k, m in out.items()}, allow_nan=False)
    back = json.loads(text)["x"]
    m = out["x"]
    assert back["mean_rel_err_pct"] is None and back["skill"] is None
    assert back["rmse_floor"] is None and back["rel_note"] == NOTE_CROSSES_ZERO
    assert back["rmse"] == m.rmse and back["n_nan_pred"] == 10 and back["unit"] == "m"
    assert set(back) == set(m.to_dict())
    # a channel without scored samples is JSON-safe too
    empty = _one([1.0, 2.0], [np.nan, np.nan]).to_dict()
    json.dumps(empty, allow_nan=False)
    assert empty["rmse"] is None and empty["n_scored"] == 0


def test_persistence_horizon_and_gaps() -> None:
    y = np.array([1.0, np.nan, 3.0, 4.0])
    np.testing.assert_array_equal(persistence_forecast(y, 1), [np.nan, 1, 1, 3])
    np.testing.assert_array_equal(persistence_forecast(y, 2), [np.nan, np.nan, 1, 1])
    with pytest.raises(ValueError):
        persistence_forecast(y, 0)


def test_shape_errors_say_what_was_expected() -> None:
    named = r"4 channels were named \(front, second, third, back\)"
    with pytest.raises(DataError, match=rf"y_pred has 5 columns but {named}"):
        channel_metrics(np.zeros((3, 4)), np.zeros((3, 5)))
    with pytest.raises(DataError, match=rf"y_true has 1 column but {named}"):
        channel_metrics(np.zeros((3, 1)), np.zeros((3, 4)))
    with pytest.raises(DataError, match=rf"y_true is 1-D \(a single channel\) but {named}") as e:
        channel_metrics(np.zeros(3), np.zeros(3))
    assert "channels=('name',)" in str(e.value)
    with pytest.raises(DataError, match="y_pred has 2 rows but y_true has 3"):
        channel_metrics(np.zeros((3, 4)), np.zeros((2, 4)))
    with pytest.raises(DataError, match="true_values has 2 rows but y_true has 3"):
        channel_metrics(np.zeros(3), np.zeros(3), channels=["x"], true_values=np.zeros(2))
    with pytest.raises(DataError, match=r"persistence has 2 columns but 1 channel was named \(x\)"):
        channel_metrics(np.zeros(3), np.zeros(3), channels=["x"], persistence=np.zeros((3, 2)))
    with pytest.raises(DataError, match=r"shape \(3, 1, 2\); expected \(n, 1\)"):
        channel_metrics(np.zeros((3, 1, 2)), np.zeros(3), channels=["x"])
    with pytest.raises(DataError, match="channel names must be distinct"):
        channel_metrics(np.zeros((3, 2)), np.zeros((3, 2)), channels=["x", "x"])


def test_one_channel_as_column_or_1d_gives_the_same() -> None:
    y = np.array([5.0, 6.0, 7.0, 8.0])
    a = channel_metrics(y, y + 0.5, channels=["x"])["x"]
    b = channel_metrics(y[:, None], (y + 0.5)[:, None], channels=["x"])["x"]
    assert a.to_dict() == b.to_dict() and a.rmse == pytest.approx(0.5)


def test_all_nan_gives_nan_metrics() -> None:
    m = _one([100.0, 100.0], [np.nan, np.nan])
    assert m.n_scored == 0 and m.n_nan_pred == 2 and m.n_rel_excluded == 0
    assert math.isnan(m.rmse) and math.isnan(m.max_rel_err_pct) and math.isnan(m.nrmse)
    m2 = _one([np.nan, np.nan], [1.0, 2.0])  # nothing measured
    assert m2.n_scored == 0 and m2.n_nan_pred == 0 and math.isnan(m2.rel_threshold)
