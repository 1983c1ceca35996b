"""Per-channel prediction metrics for any measured signal (a roller speed in rpm, a position
in m, a voltage, a level): the paper's relative errors where they mean something, and honest
ones everywhere.

For each output channel, on the *scored* samples (measurement and prediction both finite;
finite measurements without a prediction are counted in ``n_nan_pred``):

* ``bias``: the mean error (prediction minus measurement) in the channel's unit: what
  calibrated physics should bring to zero;
* ``rmse`` in the channel's unit; ``nrmse`` = RMSE / std(y) (population std of the scored
  measurements);
* ``skill`` = 1 - RMSE / RMSE_persistence, both RMSEs on the samples where the model, the
  persistence forecast and the measurement are all finite;
* against the true value, when known (the plant emulator's data), on the scored samples where
  it is finite: ``rmse_vs_true`` (the prediction as an estimate of the true value),
  ``sensor_rmse`` (the measurement's own error, measured vs true) and their ratio
  ``true_error_ratio`` (below 1: the prediction estimates the true value better than the
  sensor measures it);
* ``rmse_floor``: the lowest RMSE any predictor of the measurement can reach on the same
  samples, the RMSE of a floor oracle's predictions (:mod:`drafttwin.evaluation.limits`), when
  given;
* relative error ``100 * |y - yhat| / |y|`` in %: max, mean and "prediction accuracy"
  ``100 - mean``. A relative error is only meaningful away from zero, so:

  - the channel's *scale* is a robust maximum of ``|y|``: its 99th percentile over the
    channel's finite measurements (the samples there are to score; one spike cannot set it,
    and every model scored against the same measurement gets the same threshold);
  - ``rel_threshold = rel_floor * scale``; scored samples with ``|y| < rel_threshold`` (and
    exact zeros) are left out of the relative errors and counted in ``n_rel_excluded``. With
    the default ``rel_floor`` (:data:`DEFAULT_REL_FLOOR`, 1 %) this excludes start-up and stop samples of the FA320A
    rollers (running at 350-1800 rpm) and nothing at steady running;
  - a signal that *crosses zero* has no meaningful relative error (it explodes at every
    crossing): when more than :data:`ZERO_CROSSING_SHARE` of the finite measurements lie above
    ``+rel_threshold`` *and* more than that share lie below ``-rel_threshold``, the relative
    errors are omitted (NaN) and ``rel_note`` says why. Noise around zero during a stop stays
    inside the threshold and does not count as a crossing.

RMSE, NRMSE, skill and the limits are reported in every case. A channel without scored
samples gets NaN metrics and ``n_scored = 0``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import NamedTuple

import numpy as np
import pandas as pd

from drafttwin._constants import ROLLERS
from drafttwin._io import json_fields
from drafttwin.errors import ConfigError, DataError

DEFAULT_REL_FLOOR = 0.01
"""Relative errors leave out samples with ``|y|`` below this share of the channel's scale."""

SCALE_PERCENTILE = 99.0
"""Percentile of ``|y|`` used as the channel's scale (a maximum that ignores the top 1 %)."""

ZERO_CROSSING_SHARE = 0.01
"""A signal crosses zero when more than this share of its finite measurements lies beyond
``+rel_threshold`` and more than this share beyond ``-rel_threshold``."""

NOTE_CROSSES_ZERO = "signal crosses zero: relative errors are not defined"
NOTE_ZERO = "signal is zero everywhere: relative errors are not defined"
NOTE_ALL_LOW = "every scored sample lies below the threshold: no relative error to report"

UnitsArg = str | Mapping[str, str] | Sequence[str] | None


@dataclass(frozen=True)
class ChannelMetrics:
    """Metrics of one output channel.

    Relative errors and accuracy in %; ``rel_threshold``, ``bias`` (the mean error, prediction
    minus measurement), ``rmse``, ``rmse_persistence``, ``rmse_vs_true``, ``sensor_rmse`` and
    ``rmse_floor`` in the channel's ``unit`` (``""`` when undeclared); ``nrmse``, ``skill``
    and ``true_error_ratio`` are dimensionless. NaN where a metric cannot be computed; ``rel_note`` is
    ``None``, or why the relative errors are omitted.
    """

    channel: str
    unit: str
    n_scored: int
    n_nan_pred: int
    max_rel_err_pct: float
    mean_rel_err_pct: float
    accuracy_pct: float
    rel_threshold: float
    n_rel_excluded: int
    rel_note: str | None
    bias: float
    rmse: float
    nrmse: float
    rmse_persistence: float
    skill: float
    rmse_vs_true: float
    sensor_rmse: float
    true_error_ratio: float
    rmse_floor: float

    def to_dict(self) -> dict[str, str | int | float | None]:
        """The fields as a JSON-safe dict: NaN and infinities become ``None``."""
        return json_fields(self)


def _named(channels: Sequence[str]) -> str:
    k = len(channels)
    return f"{k} channel{'s were' if k != 1 else ' was'} named ({', '.join(channels)})"


def _as_matrix(x: np.ndarray, channels: Sequence[str], what: str) -> np.ndarray:
    """``x`` as an ``(n, len(channels))`` float64 array; a 1-D array is one channel."""
    arr = np.asarray(x, dtype=np.float64)
    k = len(channels)
    if arr.ndim == 1 and k == 1:
        return arr[:, None]
    if arr.ndim == 1:
        raise DataError(
            f"{what} is 1-D (a single channel) but {_named(channels)}",
            fix="pass one column per channel, shape (n, k), or name the one channel "
            "(channels=('name',))",
        )
    if arr.ndim != 2:
        raise DataError(
            f"{what} has shape {arr.shape}; expected (n, {k}): one row per sample and one "
            f"column per channel, as {_named(channels)}",
            fix="pass a 2-D array (or a 1-D array for a single channel)",
        )
    if arr.shape[1] != k:
        raise DataError(
            f"{what} has {arr.shape[1]} column{'s' if arr.shape[1] != 1 else ''} but "
            f"{_named(channels)}",
            fix="pass channels= with one name per column, in column order",
        )
    return arr


def _check_channels(channels: Sequence[str]) -> tuple[str, ...]:
    names = (channels,) if isinstance(channels, str) else tuple(str(c) for c in channels)
    if not names:
        raise DataError("no channel was named", fix="pass channels= with one name per column")
    if len(set(names)) != len(names):
        raise DataError(f"channel names must be distinct, got ({', '.join(names)})",
                        fix="give every column its own name")  # fmt: skip
    return names


def _units(units: UnitsArg, channels: tuple[str, ...]) -> list[str]:
    """One unit per channel: a single string for all, a sequence in channel order, or a
    mapping by channel name (extra names, e.g. inputs' units, are ignored)."""
    if units is None:
        return [""] * len(channels)
    if isinstance(units, str):
        return [units] * len(channels)
    if isinstance(units, Mapping):
        return [str(units.get(c, "")) for c in channels]
    listed = [str(u) for u in units]
    if len(listed) != len(channels):
        raise DataError(f"{len(listed)} units were given but {_named(channels)}",
                        fix="give one unit per channel, or a mapping channel -> unit")  # fmt: skip
    return listed


# ----- the metrics -------------------------------------------------------------------------
class _Relative(NamedTuple):
    max_pct: float
    mean_pct: float
    threshold: float
    n_excluded: int
    note: str | None


def _omission(measured: np.ndarray, threshold: float) -> str | None:
    """Why relative errors are not defined for this measurement, or None."""
    if not np.any(measured != 0):
        return NOTE_ZERO
    above = float(np.mean(measured > threshold))
    below = float(np.mean(measured < -threshold))
    return NOTE_CROSSES_ZERO if min(above, below) > ZERO_CROSSING_SHARE else None


def _relative(measured: np.ndarray, ys: np.ndarray, err: np.ndarray, rel_floor: float) -> _Relative:
    """Relative errors of the scored samples ``ys`` (errors ``err``) against the threshold
    set by the channel's finite measurements ``measured``."""
    nan = float("nan")
    if measured.size == 0:
        return _Relative(nan, nan, nan, 0, None)
    threshold = rel_floor * float(np.percentile(np.abs(measured), SCALE_PERCENTILE))
    low = (np.abs(ys) < threshold) | (ys == 0)
    note = _omission(measured, threshold)
    if note is None and ys.size and low.all():
        note = NOTE_ALL_LOW
    if note is not None or not ys.size:
        return _Relative(nan, nan, threshold, int(low.sum()), note)
    rel = 100.0 * np.abs(err[~low]) / np.abs(ys[~low])
    return _Relative(float(rel.max()), float(rel.mean()), threshold, int(low.sum()), None)


def _rmse(err: np.ndarray) -> float:
    return float(np.sqrt(np.mean(err**2))) if err.size else float("nan")


def _ratio(num: float, den: float) -> float:
    return num / den if np.isfinite(den) and den > 0 else float("nan")


def _one_channel(
    name: str,
    unit: str,
    y: np.ndarray,
    yhat: np.ndarray,
    pers: np.ndarray | None,
    true: np.ndarray | None,
    oracle: np.ndarray | None,
    rel_floor: float,
) -> ChannelMetrics:
    measured = np.isfinite(y)
    scored = measured & np.isfinite(yhat)
    ys = y[scored]
    err = yhat[scored] - ys
    rel = _relative(y[measured], ys, err, rel_floor)
    rmse = _rmse(err)
    rmse_p = skill = float("nan")
    if pers is not None:
        common = scored & np.isfinite(pers)
        rmse_p = _rmse(pers[common] - y[common])
        skill = 1.0 - _ratio(_rmse(yhat[common] - y[common]), rmse_p)
    vs_true, sensor = _against_truth(y, yhat, scored, true)
    floor = float("nan")
    if oracle is not None:  # on the samples the model is scored on: a paired comparison
        ok = scored & np.isfinite(oracle)
        floor = _rmse(oracle[ok] - y[ok])
    return ChannelMetrics(
        channel=name,
        unit=unit,
        n_scored=int(scored.sum()),
        n_nan_pred=int((measured & ~np.isfinite(yhat)).sum()),
        max_rel_err_pct=rel.max_pct,
        mean_rel_err_pct=rel.mean_pct,
        accuracy_pct=100.0 - rel.mean_pct,
        rel_threshold=rel.threshold,
        n_rel_excluded=rel.n_excluded,
        rel_note=rel.note,
        bias=float(err.mean()) if err.size else float("nan"),
        rmse=rmse,
        nrmse=_ratio(rmse, float(ys.std()) if ys.size else float("nan")),
        rmse_persistence=rmse_p,
        skill=skill,
        rmse_vs_true=vs_true,
        sensor_rmse=sensor,
        true_error_ratio=_ratio(vs_true, sensor),
        rmse_floor=floor,
    )


def _against_truth(
    y: np.ndarray, yhat: np.ndarray, scored: np.ndarray, true: np.ndarray | None
) -> tuple[float, float]:
    """RMSE of the prediction and of the measurement against the true value, on the scored
    samples where the true value is known (NaN without any)."""
    if true is None:
        return float("nan"), float("nan")
    ok = scored & np.isfinite(true)
    return _rmse(yhat[ok] - true[ok]), _rmse(y[ok] - true[ok])


def channel_metrics(
    y_true: np.ndarray,
    y_pred: np.ndarray,
    *,
    channels: Sequence[str] = ROLLERS,
    units: UnitsArg = None,
    persistence: np.ndarray | None = None,
    true_values: np.ndarray | None = None,
    floor_values: np.ndarray | None = None,
    rel_floor: float = DEFAULT_REL_FLOOR,
) -> dict[str, ChannelMetrics]:
    """Metrics per output channel of predictions ``y_pred`` against measurements ``y_true``.

    Args:
        y_true: measurements, ``(n, len(channels))`` (or ``(n,)`` for one channel), in each
            channel's unit; ``NaN`` = missing (not scored).
        y_pred: predictions, same shape; ``NaN`` = no prediction (counted in ``n_nan_pred``).
        channels: channel names, one per column (default: the four FA320A rollers).
        units: the channels' units: one string for all, one per channel, or a mapping by
            channel name; ``""`` where not given.
        persistence: the persistence forecast on the same rows (for skill); see
            :func:`drafttwin.models.persistence_forecast`.
        true_values: the true values (for ``rmse_vs_true`` and ``sensor_rmse``), when known.
        floor_values: a floor oracle's predictions on the same rows (for ``rmse_floor``;
            :func:`drafttwin.evaluation.limits.floor_oracle`), when known.
        rel_floor: samples with ``|y|`` below ``rel_floor`` times the channel's scale (99th
            percentile of ``|y|``) are left out of the relative errors; in ``[0, 1)``.

    Raises:
        DataError: an array's shape does not fit the named channels or ``y_true``'s rows.
        ConfigError: ``rel_floor`` outside ``[0, 1)``.
    """
    names = _check_channels(channels)
    if not 0.0 <= rel_floor < 1.0:
        raise ConfigError(f"rel_floor must be in [0, 1), got {rel_floor}", where="rel_floor",
                          fix="use a small fraction of the channel's scale, e.g. 0.01")  # fmt: skip
    unit_of = _units(units, names)
    y = _as_matrix(y_true, names, "y_true")
    others = {"y_pred": y_pred, "persistence": persistence, "true_values": true_values,
              "floor_values": floor_values}  # fmt: skip
    arrays = {k: None if v is None else _as_matrix(v, names, k) for k, v in others.items()}
    for what, arr in arrays.items():
        if arr is not None and arr.shape[0] != y.shape[0]:
            raise DataError(f"{what} has {arr.shape[0]} rows but y_true has {y.shape[0]}",
                            fix=f"give {what} one row per measured sample, on the same rows "
                                "as y_true")  # fmt: skip
    yhat, pers, true = arrays["y_pred"], arrays["persistence"], arrays["true_values"]
    oracle = arrays["floor_values"]
    assert yhat is not None
    return {
        name: _one_channel(
            name,
            unit_of[j],
            y[:, j],
            yhat[:, j],
            None if pers is None else pers[:, j],
            None if true is None else true[:, j],
            None if oracle is None else oracle[:, j],
            rel_floor,
        )
        for j, name in enumerate(names)
    }


def metrics_frame(metrics: Mapping[str, ChannelMetrics], model: str | None = None) -> pd.DataFrame:
    """A tidy DataFrame, one row per channel (plus a ``model`` column when given); NaN where
    a metric cannot be computed."""
    frame = pd.DataFrame([asdict(m) for m in metrics.values()])
    if model is not None:
        frame.insert(0, "model", model)
    return frame
