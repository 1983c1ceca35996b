"""Accuracy limits: the one-step floor and the sensor's own error, checked against closed
forms for counting encoders and against an independently fitted predictor."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drafttwin.datasets import load_default
from drafttwin.errors import DataError
from drafttwin.evaluation import accuracy_limits, channel_metrics, floor_oracle, floor_rows
from drafttwin.evaluation.limits import lag1_autocorrelation
from drafttwin.plant.config import Sensors
from drafttwin.plant.sensors import encoder_rpm, quantisation_step_rpm

RATE_HZ = 100.0


def _encoder(true_rpm: np.ndarray, jitter_s: float, seed: int) -> np.ndarray:
    """The plant's own encoder model (edges counted over 10 ms windows, 10000 counts/rev)."""
    cfg = Sensors(clock_jitter_s=jitter_s)
    return encoder_rpm(true_rpm, 1.0 / RATE_HZ, cfg, np.random.default_rng(seed))


def _wandering_speed(n: int, mean_rpm: float, seed: int) -> np.ndarray:
    """A speed steady on average that wanders by several counts per window, so the angle's
    fraction of a count at each window boundary is unforeseeable."""
    rng = np.random.default_rng(seed)
    return (mean_rpm + 3.0 * rng.standard_normal(n))[:, None]


def test_pure_quantisation_matches_the_closed_form() -> None:
    """Boundary errors uniform on one count (variance 1/12 count^2): the sensor's error is
    q*sqrt(2/12), the floor q*sqrt(1/12), 1/sqrt(2) of it."""
    true = _wandering_speed(40_000, 600.0, seed=1)
    measured = _encoder(true, jitter_s=0.0, seed=2)
    q = quantisation_step_rpm(Sensors(), RATE_HZ)
    assert q == pytest.approx(0.6)
    lim = accuracy_limits(measured, true, channels=("r",))["r"]
    assert lim.sensor_rmse == pytest.approx(q * math.sqrt(2 / 12), rel=0.01)
    # no gaps: the oracle's history is 512 errors, sqrt(1 + 1/513) above the limit
    assert lim.floor == pytest.approx(q * math.sqrt(1 / 12), rel=0.015)
    assert lag1_autocorrelation(measured[:, 0] - true[:, 0]) == pytest.approx(-0.5, abs=0.02)


def test_clock_jitter_adds_to_the_boundary_error() -> None:
    """Jitter s (seconds) at r rev/s moves each boundary by C*r*s counts (std): boundary
    variance 1/12 + (C*r*s)^2, both limits grow with it."""
    rpm, jitter = 1800.0, 2e-6
    true = _wandering_speed(40_000, rpm, seed=3)
    measured = _encoder(true, jitter_s=jitter, seed=4)
    q = quantisation_step_rpm(Sensors(), RATE_HZ)
    s_d = math.sqrt(1 / 12 + (10_000 * rpm / 60 * jitter) ** 2)
    lim = accuracy_limits(measured, true, channels=("r",))["r"]
    assert lim.sensor_rmse == pytest.approx(q * math.sqrt(2) * s_d, rel=0.015)
    assert lim.floor == pytest.approx(q * s_d, rel=0.02)


def test_history_length_sets_the_oracle_error() -> None:
    """With h past errors in a row the best linear prediction leaves q^2 s^2 (h + 2)/(h + 1):
    a gap every 3 rows leaves histories 0, 1, 2."""
    rng = np.random.default_rng(5)
    n = 90_000
    d = rng.standard_normal(n + 1)
    measured = np.diff(d)[:, None]
    true = np.zeros_like(measured)
    gap = np.arange(n) % 4 == 3
    measured[gap] = np.nan
    pred = floor_oracle(measured, true)
    err = (measured - pred)[~gap, 0]
    expected = np.mean([2.0, 3 / 2, 4 / 3])  # h = 0, 1, 2 (one third of the scored rows each)
    assert np.mean(err**2) == pytest.approx(expected, rel=0.02)


def test_floor_is_reached_by_a_fitted_predictor_and_not_beaten() -> None:
    """Independent check on the default data set: a least-squares predictor of the sensor
    error from its last 32 values, fitted on the first 70 % and scored on the rest, comes
    within a few % of the floor, and not below it. (A floor equal to the sensor's own error,
    the old 'noise floor', fails this: the fitted predictor is 30 % below that.)"""
    series = load_default()
    measured = series.values.copy()
    measured[series.metadata["outlier_mask"]] = np.nan
    true = series.truth
    n_train = int(0.7 * len(measured))
    lim = accuracy_limits(measured[n_train:], true[n_train:], channels=series.channels)
    p = 32
    for j, c in enumerate(series.channels):
        e = measured[:, j] - true[:, j]
        lags = np.column_stack([np.roll(e, k) for k in range(1, p + 1)] + [np.ones_like(e)])
        lags[:p] = np.nan
        ok = np.isfinite(lags).all(axis=1) & np.isfinite(e)
        fit_rows, test_rows = (
            ok & (np.arange(e.size) < n_train),
            ok & (np.arange(e.size) >= n_train),
        )
        coef, *_ = np.linalg.lstsq(lags[fit_rows], e[fit_rows], rcond=None)
        fitted = float(np.sqrt(np.mean((e[test_rows] - lags[test_rows] @ coef) ** 2)))
        floor, sensor = lim[c].floor, lim[c].sensor_rmse
        assert 0.99 * floor < fitted < 1.04 * floor, (c, fitted, floor)
        assert fitted < 0.8 * sensor
        assert floor == pytest.approx(sensor / math.sqrt(2), rel=0.04)


def test_simulation_floor_is_the_sensor_error() -> None:
    """A free run sees no measurement after its start: nothing of the sensor error can be
    foreseen."""
    true = _wandering_speed(5_000, 600.0, seed=6)
    measured = _encoder(true, jitter_s=0.0, seed=7)
    lim = accuracy_limits(measured, true, channels=("r",), simulation=True)["r"]
    assert lim.floor == lim.sensor_rmse
    one_step = accuracy_limits(measured, true, channels=("r",))["r"]
    assert one_step.floor < 0.75 * lim.floor


def test_no_history_crosses_a_record_or_a_gap() -> None:
    true = np.zeros((6, 1))
    measured = np.array([[1.0], [-1.0], [1.0], [5.0], [np.nan], [2.0]])
    pred = floor_oracle(measured, true, record_starts=[3])
    assert pred[0, 0] == 0.0 and pred[3, 0] == 0.0  # record starts: no history
    assert pred[1, 0] == pytest.approx(-0.5)  # h = 1: -e/2
    assert pred[2, 0] == pytest.approx(-(2 * -1.0 + 1 * 1.0) / 3)  # h = 2
    assert pred[5, 0] == 0.0  # after the gap
    observed = np.zeros_like(measured, bool)
    np.testing.assert_array_equal(floor_oracle(measured, true, observed=observed), true)


def test_premise_checked_and_bad_input_refused() -> None:
    """A sensor with independent errors (not a counting encoder) has no foreseeable part: the
    oracle's weights would be wrong, so it predicts nothing and the floor is unknown."""
    rng = np.random.default_rng(8)
    true = np.full((3_000, 2), 500.0)
    measured = true.copy()
    measured[:, 0] += np.diff(rng.standard_normal(3_001))  # counting-like
    measured[:, 1] += rng.standard_normal(3_000)  # white
    lim = accuracy_limits(measured, true, channels=("counted", "white"))
    assert math.isfinite(lim["counted"].floor) and math.isnan(lim["white"].floor)
    assert math.isfinite(lim["white"].sensor_rmse)
    with pytest.raises(DataError, match="differ in shape"):
        floor_oracle(measured, true[:, :1])
    assert lim["counted"].to_dict()["channel"] == "counted"
    assert lim["white"].to_dict()["floor"] is None


def test_floor_rows_name_the_best_model_and_any_model_below_its_floor() -> None:
    rng = np.random.default_rng(9)
    true = np.full((4_000, 2), 400.0)
    measured = true + np.diff(0.2 * rng.standard_normal((4_001, 2)), axis=0)
    oracle = floor_oracle(measured, true)
    ab = ("a", "b")
    good = channel_metrics(measured, true, channels=ab, true_values=true, floor_values=oracle)
    noisy = channel_metrics(measured, true + 0.3 * rng.standard_normal(true.shape), channels=ab,
                            true_values=true, floor_values=oracle)  # fmt: skip
    rows = floor_rows({"good": good, "noisy": {c: m.to_dict() for c, m in noisy.items()}})
    assert [r["channel"] for r in rows] == ["a", "b"]
    for r in rows:
        assert r["best_model"] == "good" and r["below_floor"] == []
        assert r["best_rmse"] == pytest.approx(good[r["channel"]].rmse)
        assert r["floor"] == pytest.approx(good[r["channel"]].rmse_floor)
        assert r["best_rmse"] > r["floor"]  # the true value alone does not reach the floor
    cheat = channel_metrics(measured, measured, channels=ab, true_values=true, floor_values=oracle)
    below = floor_rows({"good": good, "cheat": cheat})
    assert all(r["below_floor"] == ["cheat"] and r["best_model"] == "cheat" for r in below)


def test_protocol_floor_follows_the_task() -> None:
    """Scored by the protocol on plant data: one-step prediction can foresee part of the
    sensor's error; two steps ahead or in a free run nothing of it, so the floor is the
    sensor's error. Persistence stays above the floor in every task."""
    from drafttwin.evaluation import protocol
    from drafttwin.models import make_model

    data = load_default().slice(0, 6_000)
    floors = {}
    for name, kw in (("one-step", {}), ("two-step", {"horizon": 2}),
                     ("free run", {"task": "simulation"})):  # fmt: skip
        model = make_model("persistence", **kw)
        part = protocol.fit_split(model, data, train_fraction=0.7)
        ev = protocol.evaluate(model, part)
        floors[name] = ev.metrics
        for m in ev.metrics.values():
            assert m.rmse > m.rmse_floor > 0 and m.sensor_rmse > 0
    for c in data.channels:
        one, two, free = (floors[k][c] for k in ("one-step", "two-step", "free run"))
        assert one.rmse_floor == pytest.approx(one.sensor_rmse / math.sqrt(2), rel=0.05)
        assert two.rmse_floor == two.sensor_rmse and free.rmse_floor == free.sensor_rmse
