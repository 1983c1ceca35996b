"""Block features of a record as it streams in: the one implementation that the offline
diagnosis (a whole record pushed at once) and the live twin (rows as they arrive) share.

:class:`BlockStream` takes rows of measured and predicted speeds (the four rollers and the
motor) in pieces of any size and hands back each block's features once they are final; a
record pushed in one piece or row by row gives the same numbers, bit for bit. Everything is
causal: a block's features use its own rows and at most :data:`ANCHOR` + 1 rows after it
(the angle lags' gap anchors and the transient rule look that far ahead), so a live block is
final one block after it closed (at 1-s blocks and 100 Hz).

Per block (see :class:`~drafttwin.diagnosis.residuals.BlockFeatures`): the mean relative
residual of each channel with data-path spikes left out, the share of samples lost on a
channel alone, the longest run of identical values, the longest such run that moved the
channel's angle lag (a stale reading, below), and the mean angle lag of the second, third and
back roller behind the front.

A counting encoder's counts add up to its roller's angle: however long it repeats one count
(its count per sample sitting near a whole number), the lag behind the front roller stays
within an edge or two of quantisation and the drive's own wobble. A stuck encoder repeats a
stale value while the roller turns on, so the lag walks by the true count's fractional part
per sample. A run of identical values is *stale* when its lag moved by more than
:data:`STALE_EDGES` edges (one edge of the lagged roller's encoder and one of the front's
through the ratio; an encoder's edge is the smallest step its readings took so far); the
front roller's runs are judged by all three lags together (each behind the front), the
motor's (no lag) all count.
(Until 2026-11-29 only a run's length was judged: a machine whose gears leave longer healthy
runs than the tuning machines' (6-22 samples against 5-15 in 60 s) was called stuck.)

The angle lags (:class:`LagCounter`) are running sums of the counted speeds, the front's
times the kinematic ratio subtracted. A lost row (or a data-path spike) loses its counts,
unknowable to +-1 edge of quantisation each, which would add up to a random walk of several
edges over minutes; the angle is carried through the gap (gears and chain are positive
drives: the lag does not move while nobody counts) and each gap re-anchored: the lag's mean
over up to :data:`ANCHOR` rows after the gap is matched to its mean over up to as many
before. Those rows stop at a row where the lag moved by more than :data:`MOVED` times the
90th percentile of the last :data:`HISTORY` counted row steps before the row's block (a worn
mesh or a chain taking up its slack steps the lag within a few rows, 4-18 mrad against a
healthy row's 0.3-1), so a step next to a gap stays whole. (Until 2026-11-27 the windows ran
over such a step and matched it away: one lost row 30 ms before a 1.1 % chain elongation
left 3.7 of its 22 mrad. Until 2026-11-28 the percentile came from the whole record, and
the live twin had a second implementation that differed by up to 3.4 mrad.)
"""

from __future__ import annotations

import math
import warnings
from collections import deque

import numpy as np

from drafttwin.errors import DataError

N_CHANNELS = 5  # the four rollers, then the motor
N_LAGGED = 3  # the rollers whose angle is compared with the front roller's
SPIKE = 0.01  # relative distance from the block median that leaves a sample out of a level
ANGLE_SPIKE = 0.10  # ... and that makes a reading a data-path spike for the angle:
# a spike is a wrong reading, the next one back on the level, and counted it would move the
# angle by its whole size (the plant's bit errors: 15-40 % of a row, 70-180 mrad of the
# third roller); a step of the drive is a real motion that persists in the angle and is
# bounded by the lost motion it takes up: one row of 1-2 % for a worn mesh up to its 500-um
# range limit, 2-7 % on two rollers together for a 1-5 % chain elongation (measured on the
# plant). Until 2026-11-27 the 1 % band of the levels decided this too and erased them.
ANCHOR = 25  # rows each side of a gap whose mean lags are matched (0.25 s at 100 Hz)
HISTORY = 6000  # counted row steps a move is judged by (a minute at 100 Hz)
MIN_HISTORY = 10  # fewer counted steps than this: no row counts as a move yet
MOVED = 3.0  # a row's lag step this many times the 90th percentile of the history: a move
MOVING_RPM = 1.0  # below this predicted speed a roller counts as stopped (no spike test)
MRAD_PER_RPM_S = 2e3 * math.pi / 60.0  # a speed of 1 rpm for 1 s turns this many mrad
STALE_EDGES = 8.0  # a run whose lag moved this many edges is stale (see the module docstring)
MIN_ROWS_PER_BLOCK = 10  # a block's level, spikes and runs need rows to judge (10 Hz at 1 s)
STEADY_SPAN = 0.01
"""A block is steady running when the predicted front roller speed (what the set-point
commands) moves by at most this share of its mean within it and is above
:data:`MOVING_RPM`. Elsewhere (a start, a stop, a speed change, a standstill) the residual
carries the drive's acceleration, which thresholds set on steady running do not allow for:
on the FA320A plant a start-up at 12 % of full speed per second left a relative residual of
-4.1e-3 at 6 % speed and -1.3e-3 at 43 %, against -0.35e-3 at steady full speed, and a
healthy start-up, stop or standstill raised alarms (see
:class:`~drafttwin.diagnosis.cusum.CusumState`, which does not judge such blocks)."""


def check_rows_per_block(block_s: float, period_s: float) -> None:
    """Refuse a record sampled too slowly for blocks of ``block_s`` (one row per block has no
    spike test, no run and no step: the features would be empty)."""
    rows = block_s / period_s if period_s > 0 else math.inf
    if rows < MIN_ROWS_PER_BLOCK:
        fastest = MIN_ROWS_PER_BLOCK / block_s
        raise DataError(f"sampled at {1.0 / period_s:.3g} Hz: a {block_s:g}-s block holds "
                        f"{rows:.2g} samples, the diagnosis needs {MIN_ROWS_PER_BLOCK}",
                        where="data", fix=f"give a record sampled at {fastest:g} Hz or faster "
                        "(a time column in ms? head it 'time [ms]')")  # fmt: skip


class BlockStream:
    """Block features of rows pushed in pieces (see the module docstring).

    Args:
        block_s: block length, s (rounded to whole rows).
        period_s: the rows' sample period, s.
        ratio: each lagged roller's speed over the front roller's, by the kinematics
            (:func:`~drafttwin.diagnosis.residuals.roller_ratio`).
    """

    def __init__(self, block_s: float, period_s: float, ratio: np.ndarray) -> None:
        if not (math.isfinite(block_s) and block_s > 0 and math.isfinite(period_s)
                and period_s > 0):  # fmt: skip
            raise DataError(f"block {block_s} s or sample period {period_s} s is not > 0",
                            where="block_s", fix="e.g. blocks of 1 s at 100 Hz")  # fmt: skip
        self.per = max(1, int(round(block_s / period_s)))
        self.period_s = float(period_s)
        self.block_s = self.per * self.period_s
        self.lags = LagCounter(np.asarray(ratio, dtype=np.float64), self.period_s)
        self._y = np.full((self.per, N_CHANNELS), np.nan)
        self._yhat = np.full((self.per, N_CHANNELS), np.nan)
        self._t = np.zeros(self.per)
        self._k = 0  # rows in the open block
        self._waiting: deque[tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                   np.ndarray, bool]] = deque()  # fmt: skip
        self._lag_rows = np.zeros((0, N_LAGGED))  # final lags not yet averaged into a block
        self._edge_rpm = np.full(4, np.inf)  # each roller's smallest reading step so far
        self._prev: tuple[np.ndarray, np.ndarray] | None = None  # the last block's y and lags
        self.blocks = 0  # blocks handed out so far
        self.finished = False

    @property
    def pending_blocks(self) -> int:
        """Closed blocks waiting for their angle lags."""
        return len(self._waiting)

    def push(self, time_s: np.ndarray, y: np.ndarray, yhat: np.ndarray) -> list[BlockRow]:
        """Rows ``(n,)`` times, ``(n, 5)`` measured and predicted; the blocks now final."""
        if self.finished:
            raise RuntimeError("the stream was finished; start a new one")
        t = np.atleast_1d(np.asarray(time_s, dtype=np.float64))
        y, yhat = np.atleast_2d(y), np.atleast_2d(yhat)
        out: list[BlockRow] = []
        i = 0
        while i < len(t):
            take = min(self.per - self._k, len(t) - i)
            self._y[self._k : self._k + take] = y[i : i + take]
            self._yhat[self._k : self._k + take] = yhat[i : i + take]
            self._t[self._k : self._k + take] = t[i : i + take]
            self._k += take
            i += take
            if self._k == self.per:
                self._k = 0
                out += self._close()
        return out

    def finish(self) -> list[BlockRow]:
        """The end of the record: every closed block's features (the open block's rows,
        fewer than a block, are left out)."""
        self.finished = True
        return self._emit(self.lags.finish())

    def _close(self) -> list[BlockRow]:
        level, lost, run, good = block_levels(self._y, self._yhat)
        final = self.lags.add(self._y[:, :4].copy(), good[:, :4])
        step = np.abs(np.diff(self._y[:, :4], axis=0))
        step[~(step > 0)] = np.inf  # NaN too
        self._edge_rpm = np.minimum(self._edge_rpm, step.min(axis=0))
        edge = (self._edge_rpm[1:] + self.lags.ratio * self._edge_rpm[0]) * self.lags.mrad_per_row
        self._waiting.append((float(self._t[-1]), level, lost, run, self._y.copy(), edge,
                              commanded_steady(self._yhat[:, 0])))  # fmt: skip
        return self._emit(final)

    def _emit(self, lag: np.ndarray) -> list[BlockRow]:
        self._lag_rows = np.vstack([self._lag_rows, lag])
        out = []
        while self._waiting and len(self._lag_rows) >= self.per:
            t, level, lost, run, y, edge, steady = self._waiting.popleft()
            lag = self._lag_rows[: self.per]
            self._lag_rows = self._lag_rows[self.per :]
            stale = self._stale(y, lag, edge)
            out.append(BlockRow(self.blocks, t, level, lost, run, lag.mean(axis=0), stale,
                                steady))  # fmt: skip
            self._prev = (y, lag)
            self.blocks += 1
        return out

    def _stale(self, y: np.ndarray, lag: np.ndarray, edge: np.ndarray) -> np.ndarray:
        """The block's longest stale runs, judged with the previous block's rows before it."""
        if self._prev is None:
            return stale_runs(y, lag, edge, 0)
        return stale_runs(np.vstack([self._prev[0], y]), np.vstack([self._prev[1], lag]), edge,
                          len(self._prev[0]))  # fmt: skip


class BlockRow:
    """One block's features (see :class:`~drafttwin.diagnosis.residuals.BlockFeatures`)."""

    __slots__ = ("index", "time_s", "level", "lost", "run", "lag", "stale", "steady")

    def __init__(self, index: int, time_s: float, level: np.ndarray, lost: np.ndarray,
                 run: np.ndarray, lag: np.ndarray, stale: np.ndarray | None = None,
                 steady: bool = True) -> None:  # fmt: skip
        self.index, self.time_s = index, time_s
        self.level, self.lost, self.run, self.lag = level, lost, run, lag
        # without it (features kept before 2026-11-29) every run counts as stale: the old rule
        self.stale = run if stale is None else stale
        self.steady = bool(steady)  # steady running (:func:`commanded_steady`)

    @property
    def features(self) -> np.ndarray:
        """The five levels, then the three lags (:data:`~drafttwin.diagnosis.cusum.FEATURES`)."""
        return np.concatenate([self.level, self.lag])


def block_levels(y: np.ndarray, yhat: np.ndarray) -> tuple[np.ndarray, ...]:
    """One block's rows ``(per, 5)``: mean relative residual per channel (NaN with fewer than
    half the samples), share lost on a channel alone, longest run of identical values, and
    which readings the angle counts ``(per, 5)`` (all but a data-path spike)."""
    per = len(y)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = y / yhat - 1.0
    finite_r = np.isfinite(r)
    if finite_r.all():
        med = np.median(r, axis=0, keepdims=True)
    else:
        with warnings.catch_warnings():  # a block with no sample (a dropout) has no median
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(np.where(finite_r, r, np.nan), axis=0, keepdims=True)
    off = np.abs(r - med)
    ok = finite_r & (off < SPIKE)
    count = ok.sum(axis=0)
    level = np.where(count >= per / 2, np.where(ok, r, 0.0).sum(axis=0) / np.maximum(count, 1),
                     np.nan)  # fmt: skip
    finite = np.isfinite(y)
    lost = (~finite & finite.any(axis=1, keepdims=True)).sum(axis=0) / per
    stopped = yhat < MOVING_RPM
    good = ((off < ANGLE_SPIKE) & finite) | (stopped & finite)
    return level, lost, longest_runs(y), good


def commanded_steady(front_hat: np.ndarray) -> bool:
    """Whether one block's predicted front roller speeds (rpm) are steady running: above
    :data:`MOVING_RPM` and moving by at most :data:`STEADY_SPAN` of their mean. A block
    without a finite prediction counts as steady (its levels are NaN: nothing is judged)."""
    front_hat = np.asarray(front_hat, dtype=np.float64)
    if not np.isfinite(front_hat).all():
        return True
    mean = float(front_hat.mean())
    return mean >= MOVING_RPM and float(front_hat.max() - front_hat.min()) <= STEADY_SPAN * mean


def longest_runs(y: np.ndarray) -> np.ndarray:
    """Longest run of identical finite consecutive values per channel of rows ``(n, k)``."""
    same = (y[1:] == y[:-1]) & np.isfinite(y[1:])
    if not same.any():
        return np.ones(y.shape[1])
    count = np.cumsum(same, axis=0)
    # the count where each run began: the count at the last row that broke a run
    began = np.maximum.accumulate(np.where(same, 0, count), axis=0)
    out: np.ndarray = (count - began).max(axis=0) + 1.0
    return out


def stale_runs(y: np.ndarray, lag: np.ndarray, edge: np.ndarray, first: int) -> np.ndarray:
    """Per channel, the longest run of identical finite values reaching into the block that
    starts at row ``first`` of ``y (n, 5)`` (the rows before it: the previous block's) during
    which the angle lag moved by more than :data:`STALE_EDGES` ``edge`` s while over as many
    rows before the run it moved by no more than that, or than a quarter of its move during
    the run (a wrong gain walks the lag all the time, a stale value only while it repeats;
    readings that are not counts have tiny edges); ``lag (n, 3)`` and ``edge (3,)`` in mrad;
    1 when none. The front roller's run is judged by all three lags together; the motor's
    runs all count."""
    out = np.ones(N_CHANNELS)
    for c in range(N_CHANNELS):
        x = y[:, c]
        new = np.concatenate([[True], (x[1:] != x[:-1]) | ~np.isfinite(x[1:])])
        start = np.flatnonzero(new)
        end = np.concatenate([start[1:], [len(x)]])
        keep = (end - start >= 2) & (end > first) & np.isfinite(x[start])
        if not keep.any():
            continue
        start, end = start[keep], end[keep]
        if c == N_CHANNELS - 1:
            stale = np.ones(len(start), dtype=bool)
        else:
            span = end - 1 - start  # rows the lag moved over during the run
            before = np.maximum(start - span, 0)
            scale = span / np.maximum(start - before, 1)
            with np.errstate(invalid="ignore", divide="ignore"):
                during = np.abs(lag[end - 1] - lag[start]) / edge  # (runs, 3), in edges
                ahead = np.abs(lag[start] - lag[before]) / edge * scale[:, None]
            ahead_ok = np.where(start > 0, _lag_of(ahead, c), 0.0)
            moved = _lag_of(during, c)
            stale = (moved > STALE_EDGES) & (ahead_ok <= np.maximum(STALE_EDGES, moved / 4))
        if stale.any():
            out[c] = float((end - start)[stale].max())
    return out


def _lag_of(moves: np.ndarray, channel: int) -> np.ndarray:
    """Per run, the move of ``channel``'s lag among ``moves (runs, 3)``; the front roller's:
    the least of the three (each lag behind the front moves with it)."""
    out: np.ndarray = moves.min(axis=1) if channel == 0 else moves[:, channel - 1]
    return out


class LagCounter:
    """The angle lags of rows fed block by block, each row final once the rows it anchors
    to have come (see the module docstring). ``add`` takes one block's readings of the four
    rollers and which of them count; it returns the lags, mrad ``(m, 3)``, of the rows that
    became final (in order, possibly none)."""

    def __init__(self, ratio: np.ndarray, period_s: float) -> None:
        self.ratio = np.asarray(ratio, dtype=np.float64).reshape(N_LAGGED)
        self.mrad_per_row = period_s * MRAD_PER_RPM_S
        self.base = 0  # global index of the buffers' first row
        self.y = np.zeros((0, 4))
        self.good = np.zeros((0, 4), dtype=bool)
        self.step = np.zeros((0, N_LAGGED))  # rows < n_ok
        self.row_ok = np.zeros(0, dtype=bool)  # rows < n_ok
        self.cum = np.zeros((0, N_LAGGED))  # running sum of the counted steps, rows < n_ok
        self.still = np.zeros((0, N_LAGGED), dtype=bool)  # rows < n_ok
        self.lag = np.zeros((0, N_LAGGED))  # final lags, rows < n_final
        self.n_rows = self.n_ok = self.n_final = 0
        self.history = np.zeros((HISTORY, N_LAGGED))  # the last counted steps, a ring
        self.n_history = 0  # counted steps ever (the ring's write position, modulo)
        self.offset = np.zeros(N_LAGGED)
        self.prev_end = 0  # end of the last gap (global row)
        self.before: np.ndarray | None = None  # the open gap's before-means (NaN: none)
        self.pending: tuple[int, np.ndarray] | None = None  # a gap's end and before-means
        self.carried = np.zeros(N_LAGGED)  # the value an open gap holds
        self.finished = False

    # ---- rows in ---------------------------------------------------------------------------
    def add(self, y4: np.ndarray, good4: np.ndarray) -> np.ndarray:
        """One block's rows; the lags of the rows now final."""
        start = self.n_rows
        self.y = np.vstack([self.y, y4])
        self.good = np.vstack([self.good, good4])
        self.n_rows += len(y4)
        # one judge of moves per block: the history before the block
        usual, spread = self._stats()
        # the previous block's last row: its transient rule needed this block's first row
        self._count(start, usual, spread)
        self._count(self.n_rows - 1, usual, spread)
        return self._scan()

    def finish(self) -> np.ndarray:
        """No more rows: the last row's transient rule sees none after it; every lag final."""
        self.finished = True
        usual, spread = self._stats()
        self._count(self.n_rows, usual, spread)
        return self._scan()

    def _stats(self) -> tuple[np.ndarray, np.ndarray]:
        """The usual row step and its 90th-percentile spread over the history (a percentile,
        not a SD: a steady speed's quantised steps take a few values, and more than half of
        them can be one); no history yet: nothing is a move."""
        if self.n_history < MIN_HISTORY:
            return np.zeros(N_LAGGED), np.full(N_LAGGED, np.inf)
        counted = self.history[: min(self.n_history, HISTORY)]
        usual = np.median(counted, axis=0)
        return usual, np.quantile(np.abs(counted - usual), 0.9, axis=0)

    def _count(self, upto: int, usual: np.ndarray, spread: np.ndarray) -> None:
        """Make ``row_ok``, the steps, their running sum and ``still`` final up to ``upto``
        (global, exclusive), judging moves by ``usual`` and ``spread``."""
        lo, hi = self.n_ok - self.base, upto - self.base
        if hi <= lo:
            return
        rows = slice(lo, hi)
        y, good = self.y, self.good
        counted = np.isfinite(y).all(axis=1)
        together = counted & ((~good).sum(axis=1) >= 2)
        before = np.concatenate([[False], together[:-1]])
        after = np.concatenate([together[1:], [False]])
        # a transient of the drive moves two or more rollers out of the spike band together
        # for two or more rows, every roller counted: its counts are kept (a data-path spike
        # is one sample of one channel; two such on two channels in two consecutive rows come
        # about once in 1e12 rows at the plant's rate of 5e-4 per sample)
        row_ok = (good.all(axis=1) | (together & (before | after)))[rows]
        step = (y[rows, 1:] - y[rows, :1] * self.ratio) * self.mrad_per_row
        step[~row_ok] = 0.0  # carried: a positive drive keeps the lag across the gap
        last = self.cum[-1] if len(self.cum) else np.zeros(N_LAGGED)
        self.step = np.vstack([self.step, step])
        self.row_ok = np.concatenate([self.row_ok, row_ok])
        self.cum = np.vstack([self.cum, last + np.cumsum(step, axis=0)])
        self.still = np.vstack([self.still, np.abs(step - usual) <= MOVED * spread])
        self._remember(step[row_ok])
        self.n_ok = upto

    def _remember(self, steps: np.ndarray) -> None:
        """Counted steps into the history ring (the oldest overwritten)."""
        steps = steps[-HISTORY:]
        pos = np.arange(self.n_history, self.n_history + len(steps)) % HISTORY
        self.history[pos] = steps
        self.n_history += len(steps)

    # ---- gaps, anchors and final lags ------------------------------------------------------
    def _scan(self) -> np.ndarray:
        """Advance the final lags as far as the anchors allow."""
        first = self.n_final
        while self.n_final < self.n_ok:
            if self.pending is not None and not self._resolve():
                break  # the rows after the gap have not all come yet
            i = self.n_final - self.base
            ok = self.row_ok[i : self.n_ok - self.base]
            if ok[0] and self.before is not None:  # the open gap ended at the last edge
                self._close_gap()
                continue
            if ok[0]:  # a run of counted rows: up to the next gap
                n = int(np.argmin(ok)) if not ok.all() else len(ok)
                self._final(self.cum[i : i + n] + self.offset)
                continue
            if self.before is None:  # a gap opens here
                self._open_gap(self.n_final)
            n = int(np.argmax(ok)) if ok.any() else len(ok)
            self._final(np.tile(self.carried, (n, 1)))
            if n < len(ok):  # the gap ends: its after-rows decide its anchor
                self._close_gap()
        lag = self.lag[first - self.base : self.n_final - self.base]
        self._trim()
        return lag

    def _close_gap(self) -> None:
        """The open gap ended before the first row not yet final."""
        assert self.before is not None
        self.pending, self.before = (self.n_final, self.before), None
        self.prev_end = self.n_final

    def _final(self, values: np.ndarray) -> None:
        self.lag = np.vstack([self.lag, values])
        self.n_final += len(values)

    def _open_gap(self, s0: int) -> None:
        """A gap starts at row ``s0``: the mean lag over up to :data:`ANCHOR` rows before it
        (back to the last move, not before the previous gap), per roller, and the value it
        carries."""
        before = np.full(N_LAGGED, np.nan)
        lo = max(self.prev_end, s0 - ANCHOR)
        for j in range(N_LAGGED):
            moved = np.flatnonzero(~self.still[lo + 1 - self.base : s0 - self.base, j])
            b0 = lo + 1 + int(moved[-1]) if moved.size else lo
            if s0 > b0:
                before[j] = self.cum[b0 - self.base : s0 - self.base, j].mean()
        self.before = before
        self.carried = self.lag[s0 - 1 - self.base].copy() if s0 > 0 else np.zeros(N_LAGGED)

    def _resolve(self) -> bool:
        """Anchor the gap that ended (rows up to :data:`ANCHOR` after it, to the next gap
        or the record's end, up to a move): its offset is added to every later row."""
        assert self.pending is not None
        e0, before = self.pending
        ok = self.row_ok[e0 - self.base : min(e0 + ANCHOR, self.n_ok) - self.base]
        if ok.all() and self.n_ok < e0 + ANCHOR and not self.finished:
            return False
        hi = e0 + (int(np.argmin(ok)) if not ok.all() else len(ok))
        for j in range(N_LAGGED):
            moved = np.flatnonzero(~self.still[e0 - self.base : hi - self.base, j])
            a1 = e0 + int(moved[0]) if moved.size else hi
            if math.isfinite(before[j]) and a1 > e0:
                self.offset[j] += before[j] - self.cum[e0 - self.base : a1 - self.base, j].mean()
        self.pending = None
        return True

    def _trim(self) -> None:
        """Drop rows no anchor or transient rule can reach any more."""
        keep = min(self.n_final - ANCHOR - 2, self.n_ok - 2)
        if self.pending is not None:
            keep = min(keep, self.pending[0] - ANCHOR - 2)
        cut = keep - self.base
        if cut <= 0:
            return
        for name in ("y", "good", "step", "row_ok", "cum", "still", "lag"):
            setattr(self, name, getattr(self, name)[cut:])
        self.base += cut
