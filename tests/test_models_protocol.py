"""The prediction protocol (SPEC section 2): no model ever sees y_t when predicting row t."""

from __future__ import annotations

import numpy as np
import pytest

from drafttwin.data.series import MeasurementSeries
from drafttwin.models import MechanisticModel, make_model
from drafttwin.models.estimators.windows import (
    blocked_folds,
    causal_ffill,
    footprint_outside,
    gather_windows,
    target_rows,
)

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
N_TRAIN = 240
T_CUT = 290  # rows >= T_CUT are altered


@pytest.fixture(scope="module")
def data() -> MeasurementSeries:
    series, _ = make_series(360, seed=1, missing=0.01)
    return series


def _altered(series: MeasurementSeries, start: int) -> MeasurementSeries:
    rpm = series.values.copy()
    rng = np.random.default_rng(99)
    rpm[start:] = rpm[start:] * 1.03 + rng.normal(0, 5.0, rpm[start:].shape)
    return series.with_values(rpm)


def _fit(name: str, series: MeasurementSeries, horizon: int):
    extra = {} if name == "mechanistic" else {"horizon": horizon}
    model = make_model(name, **hyper_for(name, **extra))
    return model.fit(series.slice(0, N_TRAIN), MechanisticModel(mechanistic))


@pytest.mark.parametrize("horizon", [1, 2])
@pytest.mark.parametrize("name", ALL)
def test_changing_y_from_t_on_leaves_predictions_up_to_t_plus_h_minus_1(
    name: str, horizon: int, data: MeasurementSeries
) -> None:
    mech = MechanisticModel(mechanistic)
    model = _fit(name, data, horizon)
    before = model.predict_values(data, mech)
    after = model.predict_values(_altered(data, T_CUT), mech)
    keep = T_CUT + horizon  # targets <= T_CUT + h - 1 use measurements <= T_CUT - 1 only
    np.testing.assert_array_equal(before[:keep], after[:keep])
    assert np.isfinite(before[keep - 5 : keep]).all()
    if name != "mechanistic":  # the others do react to the new measurements afterwards
        assert not np.allclose(before[keep:], after[keep:])


@pytest.mark.parametrize("name", ["parallel", "md-s-l", "md-s-l+d"])
def test_mechanistic_after_t_does_not_reach_prediction_for_t(
    name: str, data: MeasurementSeries
) -> None:
    model = _fit(name, data, 1)
    t_cut = float(data.time_s[T_CUT])

    def shifted(time_s: np.ndarray) -> np.ndarray:
        return mechanistic(time_s) + np.where(time_s[:, None] > t_cut, 50.0, 0.0)

    before = model.predict(data, MechanisticModel(mechanistic))
    after = model.predict(data, MechanisticModel(shifted))
    np.testing.assert_array_equal(before[: T_CUT + 1], after[: T_CUT + 1])
    assert not np.allclose(before[T_CUT + 1 :], after[T_CUT + 1 :])


def test_crossfitted_gru_residuals_are_out_of_sample(data: MeasurementSeries) -> None:
    """The GRU prediction for a training row comes from a fold model that never saw that
    row's block: altering y inside block 0 from row s on leaves block-0 predictions up to s
    unchanged, while the other fold (trained on block 0) changes."""
    train = data.slice(0, N_TRAIN)
    mech = MechanisticModel(mechanistic)
    hyper = hyper_for("md-s-l")
    a_model = make_model("md-s-l", **hyper).fit(train, mech)
    (a0, b0), (a1, b1) = a_model.crossfit_blocks_
    s = a0 + 20
    rpm = train.values.copy()
    rpm[s:b0] *= 1.02
    b_model = make_model("md-s-l", **hyper).fit(train.with_values(rpm), mech)
    np.testing.assert_array_equal(
        a_model.crossfit_pred_[a0 : s + 1], b_model.crossfit_pred_[a0 : s + 1]
    )
    assert np.isfinite(a_model.crossfit_pred_[a0:b1]).all()
    assert not np.allclose(a_model.crossfit_pred_[a1:b1], b_model.crossfit_pred_[a1:b1])
    # the whole-training-part GRU is the one used at prediction time
    full = a_model.predict_data_driven(train)
    assert not np.allclose(full[a0:b1], a_model.crossfit_pred_[a0:b1])


def test_gather_windows_ends_at_t_minus_h() -> None:
    feats = np.arange(20, dtype=float)[:, None]
    rows = target_rows(20, window=3, horizon=2)
    assert rows[0] == 4
    x = gather_windows(feats, rows, 3, 2)
    np.testing.assert_array_equal(x[0, :, 0], [0, 1, 2])  # target 4 sees rows 0..2
    np.testing.assert_array_equal(x[:, -1, 0], rows - 2)


def test_causal_ffill_uses_only_the_past() -> None:
    x = np.array([[np.nan, 1.0], [2.0, np.nan], [np.nan, np.nan], [4.0, 5.0]])
    out = causal_ffill(x)
    expected = np.array([[np.nan, 1.0], [2.0, 1.0], [2.0, 1.0], [4.0, 5.0]])
    np.testing.assert_array_equal(out, expected)


def test_fold_footprints_avoid_the_held_out_block() -> None:
    blocks = blocked_folds(10, 110, 4)
    assert blocks[0] == (10, 35) and blocks[-1][1] == 110
    rows = np.arange(10, 110)
    keep = footprint_outside(rows, 8, 1, blocks[1])
    a, b = blocks[1]
    kept = rows[keep]
    assert ((kept < a) | (kept - 8 >= b)).all()
    assert (kept < a).any() and (kept >= b + 8).any()
