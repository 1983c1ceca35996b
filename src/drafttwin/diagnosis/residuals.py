"""Open-loop physics residuals of a record, reduced to block features.

The physics (a drive train) is simulated from the record's set-points only (open loop: a
fault cannot reach its prediction), rigid couplings reduced for speed. Per sample the
relative residual of each channel is ``y / yhat - 1``; per block of ``block_s`` seconds:

* ``level_<ch>``: mean relative residual of each roller and the motor (spikes of the data
  path, > 1 % from the block median, are left out; a block needs half its samples);
* ``lost_<ch>``: fraction of the block's samples lost on that channel alone (the logger row
  kept by the other channels);
* ``run_<ch>``: the longest run of identical consecutive values (samples), and ``stale``: the
  longest such run during which the channel's angle lag moved (a counting encoder's
  identical counts do not move it, a stuck one's do; see :mod:`~drafttwin.diagnosis.blocks`);
* ``lag_<roller>``: mean angle of the second, third and back roller against the front's
  through the kinematic ratio, mrad of that roller, from the cumulative counts (lost rows
  and data-path spikes carried through, see :mod:`~drafttwin.diagnosis.blocks`). Gears and chain are positive
  drives, so it stays put on a healthy machine and steps when a mesh's backlash grows (worn
  teeth: the driven gear trails by the wear depth over its base radius) or a chain
  elongates (research/faults.md 2.2, 2.5).

Block means of pulse counts telescope (their error falls as 1/n), which is what makes 0.01 %
visible in a second (research/faults.md, section 1). The features are computed by one
implementation, :class:`~drafttwin.diagnosis.blocks.BlockStream`, whether a record comes
whole (:func:`block_features`) or row by row (the live twin).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drafttwin._constants import ROLLERS
from drafttwin.data.series import MeasurementSeries
from drafttwin.diagnosis.blocks import (
    MOVING_RPM,
    BlockRow,
    BlockStream,
    LagCounter,
    check_rows_per_block,
)
from drafttwin.errors import DataError
from drafttwin.mechanics import DriveTrain, reduce, simulate

CHANNELS = (*ROLLERS, "motor")
LAGGED = ROLLERS[1:]  # rollers whose angle is compared with the front roller's


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
        stale: longest run of identical values that moved the angle lag, samples; ``run``
            when not measured (older feature files: every run judged by its length alone).
        steady: whether each block is steady running
            (:func:`~drafttwin.diagnosis.blocks.commanded_steady`); ``None``: all are (older
            feature files).
    """

    time_s: np.ndarray
    level: np.ndarray
    lost: np.ndarray
    run: np.ndarray
    block_s: float
    lag: np.ndarray | None = None
    stale: np.ndarray | None = None
    steady: np.ndarray | None = None

    @property
    def stale_runs(self) -> np.ndarray:
        """``stale``, or ``run`` without it."""
        return self.run if self.stale is None else self.stale

    @property
    def steady_blocks(self) -> np.ndarray:
        """``steady``, or all ``True`` without it."""
        if self.steady is None:
            return np.ones(len(self.level), dtype=bool)
        return np.asarray(self.steady, dtype=bool)

    def steady_runs(self) -> list[BlockFeatures]:
        """The record's stretches of steady running, each as a record of its own (blocks
        that are not steady left out): what the detector judges, each stretch with its own
        reference window (:class:`~drafttwin.diagnosis.cusum.CusumState`)."""
        steady = self.steady_blocks
        if steady.all():
            return [self]
        return [self._rows(slice(a, b)) for a, b in runs_of(steady)]

    def _rows(self, rows: slice) -> BlockFeatures:
        def cut(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[rows]

        return BlockFeatures(self.time_s[rows], self.level[rows], self.lost[rows],
                             self.run[rows], self.block_s, cut(self.lag), cut(self.stale),
                             cut(self.steady))  # fmt: skip

    @property
    def lags(self) -> np.ndarray:
        """``lag``, or zeros of shape ``(blocks, 3)`` without it."""
        return np.zeros((len(self.level), len(LAGGED))) if self.lag is None else self.lag

    @classmethod
    def from_rows(cls, rows: list[BlockRow], block_s: float) -> BlockFeatures:
        """The features of blocks a :class:`~drafttwin.diagnosis.blocks.BlockStream` handed
        out, in order."""
        return cls(np.array([r.time_s for r in rows]), np.vstack([r.level for r in rows]),
                   np.vstack([r.lost for r in rows]), np.vstack([r.run for r in rows]),
                   block_s, np.vstack([r.lag for r in rows]),
                   np.vstack([r.stale for r in rows]),
                   np.array([r.steady for r in rows], dtype=bool))  # fmt: skip


def runs_of(mask: np.ndarray) -> list[tuple[int, int]]:
    """The runs of ``True`` in a boolean ``mask``, as ``(first, past the last)`` indices."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], np.asarray(mask, dtype=int), [0]])))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


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


def roller_ratio(train: DriveTrain) -> np.ndarray:
    """Each of :data:`LAGGED`'s speed over the front roller's by the kinematics (gears and
    chain: the ratio every lag is counted against), ``(3,)``."""
    ratios, nodes = train.speed_ratios, train.roller_nodes
    return np.array([ratios[nodes[r]] / ratios[nodes[ROLLERS[0]]] for r in LAGGED])


def predicted_ratio(yhat: np.ndarray) -> np.ndarray:
    """:func:`roller_ratio` read off a prediction ``(n, 5)``: the median ratio over the rows
    where the front roller moves (ones when it never does)."""
    moving = yhat[:, 0] >= MOVING_RPM
    if not moving.any():
        return np.ones(len(LAGGED))
    ratio: np.ndarray = np.median(yhat[moving, 1:4] / yhat[moving, :1], axis=0)
    return ratio


def block_features(y: np.ndarray, yhat: np.ndarray, time_s: np.ndarray, block_s: float,
                   ratio: np.ndarray | None = None) -> BlockFeatures:  # fmt: skip
    """Block features of measured ``y`` against predicted ``yhat`` (both ``(n, 5)``): the
    record pushed through a :class:`~drafttwin.diagnosis.blocks.BlockStream` at once (the
    live twin pushes it row by row and gets the same numbers). ``ratio``: the kinematic
    speed ratios the lags are counted against (default: :func:`predicted_ratio`)."""
    time_s = np.asarray(time_s, dtype=np.float64)
    dt = float(np.median(np.diff(time_s))) if len(time_s) > 1 else block_s
    check_rows_per_block(block_s, dt)
    stream = BlockStream(block_s, dt, predicted_ratio(yhat) if ratio is None else ratio)
    rows = stream.push(time_s, y, yhat) + stream.finish()
    if not rows:
        raise DataError(f"the record is shorter than one block ({block_s:g} s)",
                        where="data", fix="give a longer record")  # fmt: skip
    return BlockFeatures.from_rows(rows, stream.block_s)


def angle_lag(y: np.ndarray, yhat: np.ndarray, good: np.ndarray, dt: float) -> np.ndarray:
    """The angle lags of a whole record, mrad ``(n, 3)``, with the readings ``good`` ``(n,
    >= 4)`` counted (:class:`~drafttwin.diagnosis.blocks.LagCounter`; e.g. the true lags
    of a plant record, every reading counted)."""
    counter = LagCounter(predicted_ratio(yhat), dt)
    lag = np.vstack([counter.add(y[:, :4], np.asarray(good)[:, :4]), counter.finish()])
    return lag


def record_features(train: DriveTrain, series: MeasurementSeries,
                    block_s: float = 1.0) -> BlockFeatures:  # fmt: skip
    """Block features of a record against the physics ``train``."""
    if not (math.isfinite(block_s) and block_s > 0):
        raise DataError(f"block {block_s} s is not > 0", where="--block", fix="e.g. 1 s")
    return block_features(measured(series), physics_prediction(train, series), series.time_s,
                          block_s, roller_ratio(train))  # fmt: skip
