"""Measurement data: reading, validation and preprocessing."""

from drafttwin.data.series import MeasurementSeries

__all__ = ["MeasurementSeries"]
