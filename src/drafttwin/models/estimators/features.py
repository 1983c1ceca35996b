"""Scaling of model features: min-max scalers fitted on training values only."""

from __future__ import annotations

import numpy as np

from drafttwin.data.scaling import MinMaxScaler
from drafttwin.errors import DataError
from drafttwin.models.estimators.windows import causal_ffill


def fit_scaler(values: np.ndarray, what: str) -> MinMaxScaler:
    """A MinMaxScaler fitted on ``values``; a column without finite values is a DataError."""
    try:
        return MinMaxScaler().fit(values)
    except ValueError as exc:
        raise DataError(
            f"cannot scale the {what}: a column has no finite training value",
            fix="check the training part for channels without any measurement",
        ) from exc


def scale_inputs(
    scaler: MinMaxScaler | None, u: np.ndarray, starts: tuple[int, ...] = (0,)
) -> np.ndarray:
    """Scaled, causally filled inputs ``(n, k)`` (``(n, 0)`` without inputs)."""
    if scaler is None or u.shape[1] == 0:
        return np.zeros((u.shape[0], 0))
    return causal_ffill(scaler.transform(u), starts)
