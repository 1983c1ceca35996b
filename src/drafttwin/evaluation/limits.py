"""Accuracy limits on data whose true values are known (the plant emulator's): what a
prediction of the *measured* value can reach at best, and the sensor's own error.

**The sensor error of a counting encoder.** An encoder reports the edges counted over a
sample window. With ``d_t`` the count error at window boundary ``t`` (the angle's fraction of
a count lost by the counter, plus the clock jitter of the boundary instant), the measured
speed over window ``t`` is the true interval-mean speed plus ``q * (d_{t+1} - d_t)``, ``q`` the
quantisation step. The boundary errors are independent from boundary to boundary (the angle's
fraction of a count is unforeseeable: the speed wanders by more than a count per window), so
the sensor error is a moving average of order one with coefficient -1: the boundary error
shared by two consecutive windows enters them with opposite signs, and their errors have a
lag-one autocorrelation of -1/2. A one-step predictor can foresee the ``-q * d_t`` half (the
boundary already passed); only ``q * d_{t+1}`` is new. Hence:

* ``sensor_rmse`` (the encoder's own error): RMSE of measured vs true, ``sqrt(2) * q * s_d``
  (``s_d`` the std of ``d``);
* the **one-step floor**: the RMSE of an oracle that knows the true value of the predicted
  window exactly and every earlier measurement, and predicts the sensor error as well as any
  predictor can (:func:`floor_oracle`): ``q * s_d * sqrt(1 + 1/(h + 1))`` with ``h`` past
  errors in a row, ``q * s_d`` (1/sqrt(2) of the sensor's error) after a long gap-free history.
  No predictor that knows the roller's angle only through the counts can score below it;
* in a free-run **simulation** the predictor sees no measurement after its start, so nothing
  of the sensor error can be foreseen: the floor is the sensor's own error.

The oracle needs only the sensor's structure (counts over windows), not its step or jitter:
its weights follow from the -1/2 autocorrelation. ``docs/models.md`` ("Accuracy limits")
gives the derivation and the figures measured on the default data set.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from drafttwin._io import json_fields, json_number
from drafttwin.errors import DataError

LAG1_PREMISE = (-0.6, -0.4)
"""The lag-one autocorrelation of the sensor error the oracle's premise implies is -1/2; on a
channel whose observed errors lie outside this range the premise fails (the sensor does not
count edges over windows) and the oracle gives no prediction (the floor is unknown)."""

MAX_HISTORY = 512
"""Past sensor errors the oracle uses at most: its error exceeds the limit of an infinite
history by a factor ``sqrt(1 + 1/(MAX_HISTORY + 1))`` (0.1 %)."""


def _run_lengths(finite: np.ndarray) -> np.ndarray:
    """For each row, how many rows right before it are finite (the history without a gap)."""
    n = finite.size
    idx = np.arange(n)
    last_gap = np.maximum.accumulate(np.where(~finite, idx, -1))  # last non-finite row <= t
    before = np.concatenate([[-1], last_gap[:-1]])  # ... strictly before t
    lengths: np.ndarray = idx - before - 1
    return lengths


def lag1_autocorrelation(err: np.ndarray) -> float:
    """Lag-one autocorrelation of an error series (NaN = gap), over consecutive finite pairs;
    NaN with fewer than 10 pairs."""
    a, b = err[:-1], err[1:]
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 10:
        return float("nan")
    a, b = a[ok], b[ok]
    return float(np.mean(a * b) / np.sqrt(np.mean(a * a) * np.mean(b * b)))


def _premise_holds(err: np.ndarray) -> bool:
    """Whether the observed errors look like a counting encoder's (or there are too few to
    tell, when the oracle has next to no history to use anyway)."""
    rho = lag1_autocorrelation(err)
    return not np.isfinite(rho) or LAG1_PREMISE[0] <= rho <= LAG1_PREMISE[1]


def _predict_error(err: np.ndarray, max_history: int) -> np.ndarray:
    """The best linear prediction of ``err[t]`` from the gap-free run of errors before it,
    for a moving average ``d[t+1] - d[t]`` of independent ``d``: with ``h`` past errors,
    ``-sum_{i=1..h} (h - i + 1) / (h + 1) * err[t - i]`` (the estimate of ``-d[t]`` from the
    ``h + 1`` boundaries the run links together)."""
    finite = np.isfinite(err)
    h = np.minimum(_run_lengths(finite), max_history)
    e = np.where(finite, err, 0.0)
    k = np.arange(e.size, dtype=np.float64)
    p1 = np.concatenate([[0.0], np.cumsum(e)])  # p1[t] = sum of e[:t]
    p2 = np.concatenate([[0.0], np.cumsum(k * e)])  # p2[t] = sum of k * e[k] for k < t
    t = np.arange(e.size)
    lo = t - h  # the run is e[lo:t]; weight of e[k] is (k - lo + 1) / (h + 1)
    weighted = (p2[t] - p2[lo]) - (lo - 1) * (p1[t] - p1[lo])
    prediction: np.ndarray = -weighted / (h + 1)
    return prediction


def floor_oracle(
    measured: np.ndarray,
    true: np.ndarray,
    *,
    observed: np.ndarray | None = None,
    record_starts: Sequence[int] = (0,),
    max_history: int = MAX_HISTORY,
) -> np.ndarray:
    """The floor oracle's predictions of the measured values, ``(n, k)`` (or ``(n,)``).

    The oracle knows the true value of every row and the measurements flagged ``observed``
    (default: every finite one; a free-run simulation observes only its measured start), and
    predicts each row's measurement as the true value plus the best prediction of the sensor
    error from the observed errors right before it. ``record_starts``: rows where a new
    record begins (no history crosses a record boundary). NaN where the true value is not
    known, and on a channel whose observed errors do not have the counting encoder's lag-one
    autocorrelation (:data:`LAG1_PREMISE`).
    """
    y = np.asarray(measured, dtype=np.float64)
    m = np.asarray(true, dtype=np.float64)
    if y.shape != m.shape:
        raise DataError(f"measured values {y.shape} and true values {m.shape} differ in shape",
                        fix="give the true values on the same rows and channels")  # fmt: skip
    if max_history < 0:
        raise DataError(f"max_history must be >= 0, got {max_history}", fix="use e.g. 512")
    one = y.ndim == 1
    y2, m2 = (y[:, None], m[:, None]) if one else (y, m)
    seen = np.isfinite(y2) if observed is None else np.asarray(observed, bool).reshape(y2.shape)
    err = np.where(seen & np.isfinite(y2), y2 - m2, np.nan)
    pred = np.full(y2.shape, np.nan)
    bounds = sorted({0, *(int(s) for s in record_starts if 0 < s < len(y2))}) + [len(y2)]
    for j in range(y2.shape[1]):
        if not _premise_holds(err[:, j]):
            continue
        for a, b in zip(bounds[:-1], bounds[1:], strict=False):
            pred[a:b, j] = m2[a:b, j] + _predict_error(err[a:b, j], max_history)
    return pred[:, 0] if one else pred


@dataclass(frozen=True)
class ChannelLimits:
    """Accuracy limits of one channel, in its unit, on the rows where they were measured.

    ``floor``: the lowest RMSE any predictor of the measured value can reach in the task
    (the oracle's); ``sensor_rmse``: the sensor's own error (measured vs true);
    ``n``: the rows both were computed on.
    """

    channel: str
    floor: float
    sensor_rmse: float
    n: int

    def to_dict(self) -> dict[str, str | int | float | None]:
        return json_fields(self)


def _rmse(err: np.ndarray) -> float:
    return float(np.sqrt(np.mean(err**2))) if err.size else float("nan")


def accuracy_limits(
    measured: np.ndarray,
    true: np.ndarray,
    *,
    channels: Sequence[str],
    simulation: bool = False,
    scored: np.ndarray | None = None,
    record_starts: Sequence[int] = (0,),
) -> dict[str, ChannelLimits]:
    """The floor and the sensor's error per channel, on the ``scored`` rows (default: every
    row with a finite measurement and true value).

    ``measured``: the measured values the predictors are scored against (NaN: not scored,
    and no history for the oracle); ``simulation``: free-run task, where the oracle observes
    nothing (the floor is the sensor's error).
    """
    y = np.asarray(measured, dtype=np.float64)
    m = np.asarray(true, dtype=np.float64)
    y2, m2 = (y[:, None], m[:, None]) if y.ndim == 1 else (y, m)
    observed = np.zeros(y2.shape, bool) if simulation else None
    oracle = floor_oracle(y2, m2, observed=observed, record_starts=record_starts)
    rows = np.isfinite(y2) & np.isfinite(m2)
    if scored is not None:
        rows &= np.asarray(scored, bool).reshape(y2.shape)
    out = {}
    for j, c in enumerate(channels):
        ok = rows[:, j]
        out[c] = ChannelLimits(c, _rmse(y2[ok, j] - oracle[ok, j]),
                               _rmse(y2[ok, j] - m2[ok, j]), int(ok.sum()))  # fmt: skip
    return out


def floor_rows(metrics: Mapping[str, Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per channel, the model with the lowest RMSE and its floor: ``[{"channel", "floor",
    "best_model", "best_rmse", "below_floor"}]`` (JSON-safe: ``None`` where unknown).

    ``metrics`` maps a model name to its per-channel metrics, as
    :class:`~drafttwin.evaluation.metrics.ChannelMetrics` or their ``to_dict()`` rows. The
    floor is the best model's own (on its scored samples); ``below_floor`` lists every model
    whose RMSE is below its floor: empty unless the floor is wrong.
    """

    def get(row: Any, key: str) -> float:
        value = row.get(key) if isinstance(row, Mapping) else getattr(row, key)
        return float("nan") if value is None else float(value)

    channels = list(dict.fromkeys(c for per in metrics.values() for c in per))
    out = []
    for c in channels:
        rows = {m: per[c] for m, per in metrics.items() if c in per}
        finite = {m: get(r, "rmse") for m, r in rows.items() if np.isfinite(get(r, "rmse"))}
        best = min(finite, key=finite.__getitem__) if finite else None
        below = [m for m, r in rows.items() if get(r, "rmse") < get(r, "rmse_floor")]
        out.append({
            "channel": c,
            "floor": json_number(get(rows[best], "rmse_floor")) if best else None,
            "best_model": best,
            "best_rmse": json_number(finite[best]) if best else None,
            "below_floor": below,
        })  # fmt: skip
    return out
