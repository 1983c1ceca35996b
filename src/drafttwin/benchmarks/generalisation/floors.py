"""A floor for one-step prediction of the measured speed: what an oracle that knows the
true speed can still not predict of the encoders' counting error.

The measured value is ``y_t = x_t + e_t`` (true interval-mean speed ``x_t``, sensor error
``e_t``). The counting error is correlated from one sample to the next (the quantisation
error at a window boundary enters two consecutive samples with opposite signs), so part of
``e_t`` is predictable from past errors. The oracle knows ``x_t`` exactly and predicts ``e_t``
by least squares on ``e_{t-1} .. e_{t-LAGS}``, fitted on the first half of the record and
scored on the second; the RMSE of what it leaves is the floor. A real predictor knows less
(neither ``x_t`` nor the past errors), so it cannot do better than this up to the linear
oracle's approximation; a model scoring below the floor means the floor is wrong.
"""

from __future__ import annotations

import numpy as np

LAGS = 10


def oracle_floor(measured: np.ndarray, true: np.ndarray, lags: int = LAGS) -> np.ndarray:
    """Per channel, the RMSE of the oracle's one-step prediction of the measured value.

    ``measured``: the scored measured values ``(n, channels)``, NaN where not scored (missing,
    outliers); ``true``: the true speeds on the same rows. NaN for a channel with too few
    complete rows.
    """
    err = np.asarray(measured, np.float64) - np.asarray(true, np.float64)
    return np.array([_floor_1d(err[:, j], lags) for j in range(err.shape[1])])


def _floor_1d(e: np.ndarray, lags: int) -> float:
    n = e.size
    if n <= 4 * (lags + 1):
        return float("nan")
    lagged = np.column_stack([e[lags - k : n - k] for k in range(1, lags + 1)])
    target = e[lags:]
    ok = np.isfinite(target) & np.isfinite(lagged).all(axis=1)
    x = np.column_stack([np.ones(target.size), lagged])[ok]
    y = target[ok]
    half = y.size // 2
    if half <= 2 * (lags + 1):
        return float("nan")
    coef, *_ = np.linalg.lstsq(x[:half], y[:half], rcond=None)
    resid = y[half:] - x[half:] @ coef
    return float(np.sqrt(np.mean(resid**2)))
