"""Open-loop physics residuals of a record, reduced to block features.

The physics (a drive train) is simulated from the record's set-points only (open loop: a
fault cannot reach its prediction), rigid couplings reduced for speed. Per sample the
relative residual of each channel is ``y / yhat - 1``; per block of ``block_s`` seconds:

* ``level_<ch>``: mean relative residual of each roller and the motor (spikes of the data
  path, > 1 % from the block median, are left out; a block needs half its samples);
* ``lost_<ch>``: fraction of the block's samples lost on that channel alone (the logger row
  kept by the other channels);
* ``run_<ch>``: the longest run of identical consecutive values (samples).

Block means of pulse counts telescope (their error falls as 1/n), which is what makes 0.01 %
visible in a second (research/faults.md, section 1).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from drafttwin._constants import ROLLERS
from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import DataError
from drafttwin.mechanics import DriveTrain, reduce, simulate_channels

CHANNELS = (*ROLLERS, "motor")
SPIKE = 0.01  # relative distance from the block median that marks a data-path spike


@dataclass(frozen=True)
class BlockFeatures:
    """Block features of one record (rows = blocks, in time order).

    Attributes:
        time_s: end time of each block, s.
        level: mean relative residual per channel (``CHANNELS`` order), NaN if too few samples.
        lost: fraction of samples lost on the channel alone.
        run: longest run of identical consecutive values, samples.
        block_s: block length, s.
    """

    time_s: np.ndarray
    level: np.ndarray
    lost: np.ndarray
    run: np.ndarray
    block_s: float


def physics_prediction(train: DriveTrain, series: MeasurementSeries) -> np.ndarray:
    """Open-loop prediction of the four rollers and the motor, rpm, shape ``(n, 5)``."""
    fast = reduce(train) if train.reduction is None else train
    return simulate_channels(fast, series.time_s, inputs=series.inputs, channels=CHANNELS)


def measured(series: MeasurementSeries) -> np.ndarray:
    """The record's rollers and motor, rpm, shape ``(n, 5)`` (NaN where missing)."""
    if series.motor_rpm is None:
        raise DataError("the record has no motor speed", where="motor",
                        fix="record the motor encoder (or the VFD's speed) as a 'motor' column")  # fmt: skip
    if tuple(series.channels) != ROLLERS:
        raise DataError(f"diagnosis needs the channels {', '.join(ROLLERS)}, not "
                        f"{', '.join(series.channels)}", where="channels",
                        fix="give a drawing-frame record with the four roller speeds")  # fmt: skip
    return np.column_stack([series.values, series.motor_rpm])


def block_features(y: np.ndarray, yhat: np.ndarray, time_s: np.ndarray,
                   block_s: float) -> BlockFeatures:  # fmt: skip
    """Block features of measured ``y`` against predicted ``yhat`` (both ``(n, 5)``)."""
    dt = float(np.median(np.diff(time_s)))
    per = max(1, int(round(block_s / dt)))
    nb = len(time_s) // per
    if nb < 1:
        raise DataError(f"the record is shorter than one block ({block_s:g} s)",
                        where="data", fix="give a longer record")  # fmt: skip
    n = nb * per
    with np.errstate(invalid="ignore", divide="ignore"):
        r = (y[:n] / yhat[:n] - 1.0).reshape(nb, per, -1)
    with warnings.catch_warnings():  # a block with no sample (a dropout) has no median: NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(np.where(np.isfinite(r), r, np.nan), axis=1, keepdims=True) if n else r
    ok = np.isfinite(r) & (np.abs(r - med) < SPIKE)
    count = ok.sum(axis=1)
    level = np.where(
        count >= per / 2, np.where(ok, r, 0.0).sum(axis=1) / np.maximum(count, 1), np.nan
    )
    yb = y[:n].reshape(nb, per, -1)
    finite = np.isfinite(yb)
    row_kept = finite.any(axis=2, keepdims=True)
    lost = (~finite & row_kept).sum(axis=1) / per
    return BlockFeatures(time_s[per - 1 : n : per], level, lost, _longest_runs(yb), per * dt)


def _longest_runs(yb: np.ndarray) -> np.ndarray:
    """Longest run of identical finite consecutive values per block and channel."""
    same = (yb[:, 1:, :] == yb[:, :-1, :]) & np.isfinite(yb[:, 1:, :])
    nb, m, k = same.shape
    out = np.zeros((nb, k))
    if m == 0:
        return out + 1
    run = np.zeros((nb, k))
    best = np.zeros((nb, k))
    for j in range(m):  # m = samples per block (100 at 1 s and 100 Hz): cheap
        run = np.where(same[:, j, :], run + 1, 0)
        best = np.maximum(best, run)
    return best + 1


def record_features(train: DriveTrain, series: MeasurementSeries,
                    block_s: float = 1.0) -> BlockFeatures:  # fmt: skip
    """Block features of a record against the physics ``train``."""
    if not (math.isfinite(block_s) and block_s > 0):
        raise DataError(f"block {block_s} s is not > 0", where="--block", fix="e.g. 1 s")
    return block_features(measured(series), physics_prediction(train, series), series.time_s,
                          block_s)  # fmt: skip
