"""Calibration of a drive train's physical parameters from measured records
(``drafttwin calibrate``): output-error least squares on block means, identifiability
verdicts and honest standard errors."""

from drafttwin.calibration.calibrate import Calibration, Estimate, calibrate
from drafttwin.calibration.parameters import Parameter, parameters, select, with_factors

__all__ = [
    "Calibration",
    "Estimate",
    "Parameter",
    "calibrate",
    "parameters",
    "select",
    "with_factors",
]
