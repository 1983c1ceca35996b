"""Measurement data: reading, validation and preprocessing."""

from drafttwin.data.io import read_measurements, write_measurements
from drafttwin.data.preprocess import (
    PreprocessReport,
    chronological_split,
    find_outliers,
    interpolate_missing,
    preprocess,
    smooth_outliers,
)
from drafttwin.data.scaling import MinMaxScaler
from drafttwin.data.series import MeasurementSeries

__all__ = [
    "MeasurementSeries",
    "MinMaxScaler",
    "PreprocessReport",
    "chronological_split",
    "find_outliers",
    "interpolate_missing",
    "preprocess",
    "read_measurements",
    "smooth_outliers",
    "write_measurements",
]
