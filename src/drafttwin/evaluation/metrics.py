"""Per-roller prediction metrics: the paper's relative errors and honest ones (SPEC section 3).

For each roller, on the samples where both the measurement and the prediction are finite:

* relative error ``100 * |y - yhat| / |y|`` in %, over samples with ``|y| >= min_abs_rpm``
  (the others are excluded from the relative errors and counted): max, mean, and
  "prediction accuracy" ``100 - mean``;
* RMSE in rpm; NRMSE = RMSE / std(y) (population std of the scored measurements);
* skill = 1 - RMSE / RMSE_persistence, both RMSEs on the samples where the model, the
  persistence forecast and the measurement are all finite;
* noise floor: RMSE of measured vs true speed (when the true speed is known, e.g. from the
  plant emulator), over the samples where both are finite.

NaN predictions are not scored; they are counted in ``n_nan_pred``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd

from drafttwin import ROLLERS
from drafttwin.errors import DataError


@dataclass(frozen=True)
class RollerMetrics:
    """Metrics of one roller. Relative errors and accuracy in %, RMSEs in rpm."""

    roller: str
    n_scored: int
    n_nan_pred: int
    n_excluded_low: int
    max_rel_err_pct: float
    mean_rel_err_pct: float
    accuracy_pct: float
    rmse_rpm: float
    nrmse: float
    rmse_persistence_rpm: float
    skill: float
    noise_floor_rpm: float

    def to_dict(self) -> dict[str, float | int | str]:
        return asdict(self)


def persistence_forecast(rpm: np.ndarray, horizon: int = 1) -> np.ndarray:
    """The naive forecast ``yhat_T = y_{T-horizon}`` (last observed value at or before
    ``T - horizon`` when samples are missing); ``NaN`` where no earlier value exists. rpm in,
    rpm out, same shape."""
    if horizon < 1:
        raise ValueError("horizon must be >= 1")
    y = np.asarray(rpm, dtype=np.float64)
    squeeze = y.ndim == 1
    y2 = y[:, None] if squeeze else y
    n = y2.shape[0]
    rows = np.where(np.isnan(y2), 0, np.arange(n)[:, None])
    np.maximum.accumulate(rows, axis=0, out=rows)
    filled = y2[rows, np.arange(y2.shape[1])[None, :]]
    out = np.full_like(y2, np.nan)
    if n > horizon:
        out[horizon:] = filled[: n - horizon]
    return out[:, 0] if squeeze else out


def _as_matrix(x: np.ndarray | None, n_cols: int, what: str) -> np.ndarray | None:
    if x is None:
        return None
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim == 1 and n_cols == 1:
        arr = arr[:, None]
    if arr.ndim != 2 or arr.shape[1] != n_cols:
        raise DataError(f"{what} has shape {arr.shape}; expected (n, {n_cols})")
    return arr


def _rmse(err: np.ndarray) -> float:
    return float(np.sqrt(np.mean(err**2))) if err.size else float("nan")


def _ratio(num: float, den: float) -> float:
    return num / den if np.isfinite(den) and den > 0 else float("nan")


def _roller_metrics(
    name: str,
    y: np.ndarray,
    yhat: np.ndarray,
    pers: np.ndarray | None,
    true: np.ndarray | None,
    min_abs_rpm: float,
) -> RollerMetrics:
    y_ok = np.isfinite(y)
    scored = y_ok & np.isfinite(yhat)
    err = yhat[scored] - y[scored]
    ys = y[scored]
    high = np.abs(ys) >= min_abs_rpm
    rel = 100.0 * np.abs(err[high]) / np.abs(ys[high])
    mean_rel = float(rel.mean()) if rel.size else float("nan")
    rmse = _rmse(err)
    rmse_p = skill = float("nan")
    if pers is not None:
        common = scored & np.isfinite(pers)
        rmse_p = _rmse(pers[common] - y[common])
        skill = 1.0 - _ratio(_rmse(yhat[common] - y[common]), rmse_p)
    floor = float("nan")
    if true is not None:
        both = y_ok & np.isfinite(true)
        floor = _rmse(y[both] - true[both])
    return RollerMetrics(
        roller=name,
        n_scored=int(scored.sum()),
        n_nan_pred=int((y_ok & ~np.isfinite(yhat)).sum()),
        n_excluded_low=int((~high).sum()),
        max_rel_err_pct=float(rel.max()) if rel.size else float("nan"),
        mean_rel_err_pct=mean_rel,
        accuracy_pct=100.0 - mean_rel,
        rmse_rpm=rmse,
        nrmse=_ratio(rmse, float(ys.std()) if ys.size else float("nan")),
        rmse_persistence_rpm=rmse_p,
        skill=skill,
        noise_floor_rpm=floor,
    )


def evaluate(
    y_true: np.ndarray,
    y_pred: np.ndarray,
    *,
    rollers: Sequence[str] = ROLLERS,
    persistence: np.ndarray | None = None,
    true_speed: np.ndarray | None = None,
    min_abs_rpm: float = 1.0,
) -> dict[str, RollerMetrics]:
    """Metrics per roller of predictions ``y_pred`` against measurements ``y_true``.

    Args:
        y_true: measured speeds in rpm, ``(n, len(rollers))``; ``NaN`` = missing (not scored).
        y_pred: predicted speeds in rpm, same shape; ``NaN`` = no prediction (counted).
        rollers: column names.
        persistence: the persistence forecast on the same rows (for skill); see
            :func:`persistence_forecast`.
        true_speed: true speeds in rpm (for the noise floor), when known.
        min_abs_rpm: samples with ``|y| <`` this are excluded from relative errors.
    """
    k = len(rollers)
    y = _as_matrix(y_true, k, "y_true")
    yhat = _as_matrix(y_pred, k, "y_pred")
    assert y is not None and yhat is not None
    pers = _as_matrix(persistence, k, "persistence")
    true = _as_matrix(true_speed, k, "true_speed")
    for name, arr in (("y_pred", yhat), ("persistence", pers), ("true_speed", true)):
        if arr is not None and arr.shape[0] != y.shape[0]:
            raise DataError(f"{name} has {arr.shape[0]} rows but y_true has {y.shape[0]}")
    return {
        name: _roller_metrics(
            name,
            y[:, j],
            yhat[:, j],
            None if pers is None else pers[:, j],
            None if true is None else true[:, j],
            min_abs_rpm,
        )
        for j, name in enumerate(rollers)
    }


def metrics_frame(metrics: Mapping[str, RollerMetrics], model: str | None = None) -> pd.DataFrame:
    """A tidy DataFrame, one row per roller (plus a ``model`` column when given)."""
    frame = pd.DataFrame([m.to_dict() for m in metrics.values()])
    if model is not None:
        frame.insert(0, "model", model)
    return frame
