"""Open-loop physics residuals of a record, reduced to block features.

The physics (a drive train) is simulated from the record's set-points only (open loop: a
fault cannot reach its prediction), rigid couplings reduced for speed. Per sample the
relative residual of each channel is ``y / yhat - 1``; per block of ``block_s`` seconds:

* ``level_<ch>``: mean relative residual of each roller and the motor (spikes of the data
  path, > 1 % from the block median, are left out; a block needs half its samples);
* ``lost_<ch>``: fraction of the block's samples lost on that channel alone (the logger row
  kept by the other channels);
* ``run_<ch>``: the longest run of identical consecutive values (samples);
* ``lag_<roller>``: mean angle of the second, third and back roller against the front's
  through the kinematic ratio, mrad of that roller, from the cumulative counts (lost rows
  and data-path spikes carried through, see :func:`angle_lag`). Gears and chain are positive
  drives, so it stays put on a healthy machine and steps when a mesh's backlash grows (worn
  teeth: the driven gear trails by the wear depth over its base radius) or a chain
  elongates (research/faults.md 2.2, 2.5).

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
from drafttwin.mechanics import DriveTrain, reduce, simulate

CHANNELS = (*ROLLERS, "motor")
LAGGED = ROLLERS[1:]  # rollers whose angle is compared with the front roller's
SPIKE = 0.01  # relative distance from the block median that leaves a sample out of a level
ANGLE_SPIKE = 0.10  # ... and that makes a reading a data-path spike for the angle:
# a spike is a wrong reading, the next one back on the level, and counted it would move the
# angle by its whole size (the plant's bit errors: 15-40 % of a row, 70-180 mrad of the
# third roller); a step of the drive is a real motion that persists in the angle and is
# bounded by the lost motion it takes up: one row of 1-2 % for a worn mesh up to its 500-um
# range limit, 2-7 % on two rollers together for a 1-5 % chain elongation (measured on the
# plant). Until 2026-11-27 the 1 % band of the levels decided this too and erased them.
ANCHOR = 25  # rows each side of a gap whose mean lags are matched (0.25 s at 100 Hz)
HISTORY = 6000  # counted rows a block-by-block run judges a move by (a minute at 100 Hz)
MOVED = 3.0  # a row's lag step this many times the record's 90th percentile: the drive moved
MOVING_RPM = 1.0  # below this predicted speed a roller counts as stopped (no spike test)


@dataclass(frozen=True)
class BlockFeatures:
    """Block features of one record (rows = blocks, in time order).

    Attributes:
        time_s: end time of each block, s.
        level: mean relative residual per channel (``CHANNELS`` order), NaN if too few samples.
        lost: fraction of samples lost on the channel alone.
        run: longest run of identical consecutive values, samples.
        block_s: block length, s.
        lag: mean angle of each of ``LAGGED`` against the front roller, mrad (see module);
            zeros when not measured (older feature files).
    """

    time_s: np.ndarray
    level: np.ndarray
    lost: np.ndarray
    run: np.ndarray
    block_s: float
    lag: np.ndarray | None = None

    @property
    def lags(self) -> np.ndarray:
        """``lag``, or zeros of shape ``(blocks, 3)`` without it."""
        return np.zeros((len(self.level), len(LAGGED))) if self.lag is None else self.lag


def physics_prediction(train: DriveTrain, series: MeasurementSeries) -> np.ndarray:
    """Open-loop prediction of the four rollers and the motor, rpm, shape ``(n, 5)``."""
    fast = reduce(train) if train.reduction is None else train
    return simulate(fast, time_s=series.time_s, inputs=series.inputs).channels(CHANNELS)


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


def block_features(y: np.ndarray, yhat: np.ndarray, time_s: np.ndarray, block_s: float,
                   carry: LagCarry | None = None) -> BlockFeatures:  # fmt: skip
    """Block features of measured ``y`` against predicted ``yhat`` (both ``(n, 5)``);
    ``carry``: the angle lags go on from the rows fed before (a record fed block by block)."""
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
    off = np.abs(r - med)
    ok = np.isfinite(r) & (off < SPIKE)
    count = ok.sum(axis=1)
    level = np.where(
        count >= per / 2, np.where(ok, r, 0.0).sum(axis=1) / np.maximum(count, 1), np.nan
    )
    yb = y[:n].reshape(nb, per, -1)
    finite = np.isfinite(yb)
    row_kept = finite.any(axis=2, keepdims=True)
    lost = (~finite & row_kept).sum(axis=1) / per
    stopped = (yhat[:n] < MOVING_RPM).reshape(nb, per, -1)
    # the angle counts every reading but a data-path spike (:data:`ANGLE_SPIKE`)
    good = (((off < ANGLE_SPIKE) & finite) | (stopped & finite)).reshape(n, -1)
    if carry is None:
        lag = angle_lag(y[:n], yhat[:n], good, dt)
    else:
        lag = carry.extend(y[:n], yhat[:n], good, dt)
    return BlockFeatures(time_s[per - 1 : n : per], level, lost, _longest_runs(yb), per * dt,
                         lag.reshape(nb, per, -1).mean(axis=1))  # fmt: skip


class LagCarry:
    """The angle lags of a record fed block by block (the live twin), as :func:`angle_lag`
    gives them over the whole record: each block is computed after the last :data:`ANCHOR`
    rows of the rows before it, so the lags go on where they stopped and a gap at a block's
    edge is bridged with rows on both sides, not lost with its counts (a lost edge on every
    such gap would add up to a random walk, and to false alarms on the lag streams).

    Not the same numbers: a gap is anchored only with the rows at hand (the offline lags may
    use up to :data:`ANCHOR` rows past a block's end), and each call is aligned to the
    carried rows. On 10.5-min plant records of the fault benchmark the two differ by up to
    3.4 mrad, the block-fed lags' SD up to 3.3 times larger (four records, 2026-11-27; the
    speed ratio is not the cause: with the whole record's ratio the numbers are the same)."""

    def __init__(self) -> None:
        self.y: np.ndarray | None = None
        self.yhat = self.good = self.lag = np.zeros((0, 0))
        self.steps = np.zeros((0, len(LAGGED)))  # counted row steps: what a move is

    def extend(self, y: np.ndarray, yhat: np.ndarray, good: np.ndarray,
               dt: float) -> np.ndarray:  # fmt: skip
        """Lags of the new rows ``(n, 3)``, continuing the rows fed before."""
        step, row_ok = row_steps(y, yhat, good, dt)
        self.steps = np.vstack([self.steps, step[row_ok]])[-HISTORY:]
        if self.y is None:
            lag = angle_lag(y, yhat, good, dt, self.steps)
            y_all, yhat_all, good_all, lag_all = y, yhat, good, lag
        else:
            m = len(self.y)
            y_all, yhat_all = np.vstack([self.y, y]), np.vstack([self.yhat, yhat])
            good_all = np.vstack([self.good, good])
            lag_all = angle_lag(y_all, yhat_all, good_all, dt, self.steps)
            ref = _reference_rows(np.asarray(self.good[:, : len(LAGGED) + 1].all(axis=1)))
            lag_all += (self.lag[ref] - lag_all[:m][ref]).mean(axis=0)
            lag = lag_all[m:]
        self.y, self.yhat = y_all[-ANCHOR:].copy(), yhat_all[-ANCHOR:].copy()
        self.good, self.lag = good_all[-ANCHOR:].copy(), lag_all[-ANCHOR:].copy()
        return lag


def _reference_rows(row_ok: np.ndarray) -> np.ndarray:
    """Rows of the carried context whose lags the new computation is matched to: the good
    rows before its first gap (their lags were bridged with rows on both sides), else the
    good rows after its last gap, else its last row."""
    bad = np.flatnonzero(~row_ok)
    if bad.size == 0:
        return np.flatnonzero(row_ok)
    before, after = (
        np.flatnonzero(row_ok[: bad[0]]),
        bad[-1] + 1 + np.flatnonzero(row_ok[bad[-1] + 1 :]),
    )
    for rows in (before, after):
        if rows.size:
            return rows
    return np.array([len(row_ok) - 1])


def row_steps(y: np.ndarray, yhat: np.ndarray, good: np.ndarray,
              dt: float) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Each row's step of the lags, mrad ``(n, 3)`` (0 where not counted), and which rows
    are counted ``(n,)``: all four rollers ``good``, or moving together
    (:func:`coherent_motion`)."""
    k = len(LAGGED) + 1
    moving = yhat[:, 0] >= MOVING_RPM
    if not moving.any():
        return np.zeros((len(y), k - 1)), np.ones(len(y), dtype=bool)
    ratio = np.median(yhat[moving, 1:k] / yhat[moving, :1], axis=0)
    row_ok = good[:, :k].all(axis=1) | coherent_motion(y[:, :k], good[:, :k])
    step = (y[:, 1:k] - y[:, :1] * ratio) * (dt * 2e3 * np.pi / 60.0)  # mrad per row
    step[~row_ok] = 0.0  # carried: a positive drive keeps the lag across the gap
    return step, row_ok


def angle_lag(y: np.ndarray, yhat: np.ndarray, good: np.ndarray, dt: float,
              history: np.ndarray | None = None) -> np.ndarray:  # fmt: skip
    """Angle of each of ``LAGGED`` minus the front roller's times the kinematic ratio (the
    prediction's median speed ratio), mrad of that roller, per sample ``(n, 3)``.

    The angle is the running sum of the counted speeds over rows where all four rollers
    are ``good``. A lost row (or a data-path spike) loses its counts, unknowable to +-1 edge
    of quantisation each, which would add up to a random walk of several edges over
    minutes; the angle is carried through the gap (positive drives: the lag does not move
    while nobody counts) and each gap re-anchored: the lag's mean over up to :data:`ANCHOR`
    rows after the gap is matched to its mean over up to as many before. Those rows stop
    at a row where the lag moved by more than :data:`MOVED` times the 90th percentile of
    the record's row steps (a worn mesh or a chain taking up its slack steps the lag within
    a few rows, 4-18 mrad against a healthy row's 0.3-1), so a step next to a gap stays
    whole. (Until 2026-11-27 the windows ran over such a step and matched it away: one lost
    row 30 ms before a 1.1 % chain elongation left 3.7 of its 22 mrad.) ``history``: the
    counted row steps to judge a move by (:class:`LagCarry` passes the rows fed so far),
    else this call's.
    """
    k = len(LAGGED) + 1
    step, row_ok = row_steps(y, yhat, good, dt)
    lag = np.cumsum(step, axis=0)
    bad = np.flatnonzero(~row_ok)
    if bad.size == 0:
        return lag
    # a row whose lag moved more than MOVED times the 90th percentile of the record's row
    # steps (the drive moved: a worn mesh's or a chain's step) ends an anchor window, so no
    # step is matched away (a percentile, not a SD: a steady speed's quantised steps take
    # a few values, and more than half of them can be one)
    counted = step[row_ok] if history is None else history
    if len(counted):
        usual = np.median(counted, axis=0)
        spread = np.quantile(np.abs(counted - usual), 0.9, axis=0)
    else:
        usual, spread = np.zeros(k - 1), np.full(k - 1, np.inf)
    still = np.abs(step - usual) <= MOVED * spread
    # runs of lost rows: [start, end) each
    new_run = np.concatenate([[True], np.diff(bad) > 1])
    starts = bad[new_run]
    ends = np.concatenate([bad[np.flatnonzero(new_run)[1:] - 1], bad[-1:]]) + 1
    offset = np.zeros(k - 1)
    nxt = np.concatenate([starts[1:], [len(y)]])
    prev_end = 0
    for s0, e0, s1 in zip(starts, ends, nxt, strict=True):
        lag[prev_end:s0] += offset
        lo, hi = max(prev_end, s0 - ANCHOR), min(s1, e0 + ANCHOR)
        for j in range(k - 1):
            # rows before the gap back to the last move, rows after it up to the next
            moved = np.flatnonzero(~still[lo + 1 : s0, j])
            b0 = lo + 1 + int(moved[-1]) if moved.size else lo
            moved = np.flatnonzero(~still[e0:hi, j])
            a1 = e0 + int(moved[0]) if moved.size else hi
            if s0 > b0 and a1 > e0:
                gap = lag[b0:s0, j].mean() - (lag[e0:a1, j].mean() + offset[j])
                offset[j] += gap
        lag[s0:e0] = lag[s0 - 1] if s0 > 0 else 0.0
        prev_end = e0
    lag[prev_end:] += offset
    return lag


def coherent_motion(y: np.ndarray, good: np.ndarray) -> np.ndarray:
    """Rows ``(n,)`` where two or more rollers leave the angle's spike band together for two
    or more samples in a row, every roller counted: a transient of the drive, whose counts
    the angle keeps (a chain's slack taken up beyond the band would otherwise be bridged). A
    data-path spike is one sample of one channel; independent spikes on two channels in two
    consecutive rows come about once in 1e12 rows at the plant's rate of 5e-4 per sample."""
    counted = np.isfinite(y).all(axis=1)
    together = counted & ((~good).sum(axis=1) >= 2)
    before = np.concatenate([[False], together[:-1]])
    after = np.concatenate([together[1:], [False]])
    transient: np.ndarray = together & (before | after)
    return transient


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
