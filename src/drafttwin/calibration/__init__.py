"""Calibration of a drive train's physical parameters from measured records
(``drafttwin calibrate``): output-error least squares on block means, identifiability
verdicts and honest standard errors."""

from drafttwin.calibration.registry import Parameter, parameters, select, with_factors
from drafttwin.calibration.stages import Calibration, Estimate, calibrate

__all__ = [
    "Calibration",
    "Estimate",
    "Parameter",
    "calibrate",
    "parameters",
    "select",
    "with_factors",
]
