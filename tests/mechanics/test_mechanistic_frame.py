"""The physics' predict returns the labelled frame every model returns; predict_values the
array the estimators and hybrids combine with."""

from __future__ import annotations

import numpy as np
import pandas as pd

from drafttwin.data.series import MeasurementSeries
from drafttwin.models.mechanistic import MechanisticModel


def _series(n: int, t0: float = 0.0) -> MeasurementSeries:
    t = t0 + 0.01 * np.arange(1, n + 1)
    return MeasurementSeries(t, np.zeros((n, 2)), channels=("y", "z"), units={"y": "m"})


def test_predict_is_a_labelled_frame_with_the_values_of_predict_values():
    series = _series(30)
    values = np.column_stack([np.sin(series.time_s), np.cos(series.time_s)])
    physics = MechanisticModel(values, channels=("y", "z"))
    frame = physics.predict(series)
    assert isinstance(frame, pd.DataFrame)
    assert frame.columns.tolist() == ["time", "y", "z"]
    np.testing.assert_array_equal(frame["time"], series.time_s)
    np.testing.assert_array_equal(frame[["y", "z"]].to_numpy(), physics.predict_values(series))
    np.testing.assert_array_equal(physics.predict_values(series), values)
    assert frame.attrs["units"]["y"] == "m"
    assert physics.predict(series, ["z"]).columns.tolist() == ["time", "z"]


def test_a_series_of_several_records_gets_the_record_column():
    two = MeasurementSeries.concat([_series(10), _series(12, t0=5.0)])
    frame = MechanisticModel(lambda t: np.column_stack([t, 2 * t])).predict(two)
    assert frame["record"].tolist() == [0] * 10 + [1] * 12
    np.testing.assert_allclose(frame["z"], 2 * two.time_s)
