"""Measurement data: reading, validation and preprocessing."""

from drafttwin.data.gaps import interpolate_missing
from drafttwin.data.io import read_measurements, write_measurements
from drafttwin.data.preprocessing import (
    DEFAULT_TRAIN_FRACTION,
    PreprocessReport,
    chronological_split,
    find_measured_outliers,
    find_outliers,
    outlier_scale,
    outlier_scales,
    preprocess,
    reject_spikes_causal,
    smooth_outliers,
)
from drafttwin.data.scaling import MinMaxScaler
from drafttwin.data.series import MeasurementSeries

__all__ = [
    "DEFAULT_TRAIN_FRACTION",
    "MeasurementSeries",
    "MinMaxScaler",
    "PreprocessReport",
    "chronological_split",
    "find_measured_outliers",
    "find_outliers",
    "interpolate_missing",
    "outlier_scale",
    "outlier_scales",
    "preprocess",
    "read_measurements",
    "reject_spikes_causal",
    "smooth_outliers",
    "write_measurements",
]
