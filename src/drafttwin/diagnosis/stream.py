"""The diagnosis fed as a machine runs: blocks, decisions, and the windows whose shift is
ranked. One implementation for both paths: the offline diagnosis
(:class:`~drafttwin.diagnosis.diagnose.Diagnoser`) pushes a whole record through a
:class:`DiagnosisStream` and ranks its windows at once; the live twin pushes each machine's
rows as they arrive and ranks the windows in a worker process. The same rows give the same
alarms, windows and causes.

Per block the detector's :class:`~drafttwin.diagnosis.cusum.CusumState` decides. After an
alarm the stream goes on (the CUSUMs restart from a new reference window, as at a record's
start) and keeps a *window*: the :data:`POST_S` seconds of blocks after a CUSUM alarm (the
shift of a ramp grows by then), handed out as a :class:`RankRequest` when it is full, or
when the record ends with at least :data:`MIN_BLOCKS` of them (else the blocks from the
change estimate on). A sensor rule names its channel at once and is raised once per episode;
its window sizes the fault on the channel's own samples (:mod:`~drafttwin.diagnosis.sensors`),
and a sensor rule that fires from a machine alarm's change estimate to the window's end takes
the window over: a stuck or dropped encoder corrupts its level and angle lag at once, so a
CUSUM can alarm a block before the sensor rule does, and the ranking would blame a machine
element for the sensor's fault.
"""

from __future__ import annotations

from collections import deque
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from drafttwin.diagnosis.blocks import BlockRow, BlockStream
from drafttwin.diagnosis.clearance import Clearance
from drafttwin.diagnosis.cusum import FEATURES, STREAMS, Alarm, CusumState
from drafttwin.diagnosis.detect import Detection, FaultDetector
from drafttwin.diagnosis.learning import Learner
from drafttwin.diagnosis.residuals import CHANNELS, BlockFeatures

POST_S = 20.0
"""Seconds of blocks after an alarm whose shift is ranked (a sensor fault: sized)."""
BLOCK_S = 1.0
"""Block length of a machine that learns without a prior, s."""
MIN_BLOCKS = 5
"""Fewest blocks after the alarm a window cut short by the record's end is ranked on."""


@dataclass(frozen=True)
class Window:
    """One block the stream remembers: its end time (s), index (among the blocks its
    detector decided, the frame of the alarms and the baseline), features
    (:data:`~drafttwin.diagnosis.cusum.FEATURES`), lost shares, longest runs and longest
    stale runs (see :mod:`~drafttwin.diagnosis.blocks`)."""

    time_s: float
    block: int
    row: np.ndarray
    lost: np.ndarray
    run: np.ndarray
    stale: np.ndarray


@dataclass(frozen=True)
class RankRequest:
    """What to rank (or, for a sensor rule, to size) after an alarm: the window's blocks
    (end times, indices, features minus the baseline at the alarm) and, for a sensor fault,
    the cause its rule named with the channel's samples around it."""

    alarm: Alarm
    base: np.ndarray  # the baseline at the alarm (FEATURES)
    time_s: np.ndarray
    blocks: np.ndarray
    deviation: np.ndarray
    block_s: float
    complete: bool = True  # the window ran its full length (False: the record ended first)
    sensor: tuple[str, str] | None = None  # (channel, kind) a sensor rule named
    sensor_window: Window | None = None  # the block whose rule named it
    raw_time_s: np.ndarray | None = None  # the stream's recent samples, for the sizing
    raw_y: np.ndarray | None = None
    machine: str = ""

    @property
    def n_blocks(self) -> int:
        return len(self.blocks)

    @property
    def shift(self) -> np.ndarray:
        """The window's mean deviation (levels, then lags)."""
        return np.asarray(self.deviation.mean(axis=0))

    def to_doc(self) -> dict[str, Any]:
        """JSON-able (NaN as null): a request kept to be ranked later (a twin stopped first)."""
        w = self.sensor_window

        def arr(a: np.ndarray | None) -> Any:
            return None if a is None else np.where(np.isfinite(a), a, np.nan).tolist()

        return {"alarm": asdict(self.alarm), "base": arr(self.base), "time_s": arr(self.time_s),
                "blocks": self.blocks.astype(int).tolist(), "deviation": arr(self.deviation),
                "block_s": self.block_s, "complete": self.complete,
                "sensor": None if self.sensor is None else list(self.sensor),
                "sensor_window": None if w is None else {
                    "time_s": w.time_s, "block": w.block, "row": arr(w.row), "lost": arr(w.lost),
                    "run": arr(w.run), "stale": arr(w.stale)},
                "raw_time_s": arr(self.raw_time_s), "raw_y": arr(self.raw_y),
                "machine": self.machine}  # fmt: skip

    @classmethod
    def from_doc(cls, doc: dict[str, Any]) -> RankRequest:
        """From :meth:`to_doc`, every field checked (``ValueError`` naming what is wrong)."""
        nf, nc = len(FEATURES), len(CHANNELS)

        def arr(v: Any, shape: tuple[int, ...], name: str, finite: bool = True) -> np.ndarray:
            a = np.array([[np.nan if x is None else x for x in r] for r in v] if v and
                         isinstance(v[0], list) else [np.nan if x is None else x for x in v],
                         dtype=np.float64)  # fmt: skip
            if len(shape) == 2 and a.size == 0:
                a = a.reshape(0, shape[1])
            ok = all(s in (-1, d) for s, d in zip(shape, a.shape, strict=False))
            if a.ndim != len(shape) or not ok or (finite and not np.isfinite(a).all()):
                raise ValueError(f"{name} has shape {a.shape} or is not finite")
            return a

        try:
            al = doc["alarm"]
            alarm = Alarm(float(al["time_s"]), int(al["block"]), str(al["test"]),
                          int(al["direction"]), float(al["change_s"]), str(al["rule"]))  # fmt: skip
            time_s = arr(doc["time_s"], (-1,), "time_s")
            blocks = np.asarray(doc["blocks"], dtype=int)
            dev = arr(doc["deviation"], (len(time_s), nf), "deviation", finite=False)
            w, sensor = doc["sensor_window"], doc["sensor"]
            window = None if w is None else Window(
                float(w["time_s"]), int(w["block"]), arr(w["row"], (nf,), "row", finite=False),
                arr(w["lost"], (nc,), "lost"), arr(w["run"], (nc,), "run"),
                # a window kept before 2026-11-29 has no stale runs: its runs judged alone
                arr(w.get("stale", w["run"]), (nc,), "stale"))  # fmt: skip
            raw_t = (
                None if doc["raw_time_s"] is None else arr(doc["raw_time_s"], (-1,), "raw_time_s")
            )
            raw_y = (
                None if doc["raw_y"] is None else arr(doc["raw_y"], (-1, nc), "raw_y", finite=False)
            )
            return cls(alarm, arr(doc["base"], (nf,), "base", finite=False), time_s, blocks, dev,
                       float(doc["block_s"]), bool(doc["complete"]),
                       None if sensor is None else (str(sensor[0]), str(sensor[1])), window,
                       raw_t, raw_y, str(doc["machine"]))  # fmt: skip
        except (KeyError, TypeError, IndexError) as exc:
            raise ValueError(f"{type(exc).__name__}: {exc}") from None


@dataclass
class Step:
    """What a piece of rows (or a block) brought: the alarms raised, the windows that
    closed, and the detector a learning state ended with."""

    alarms: list[Alarm] = field(default_factory=list)
    requests: list[RankRequest] = field(default_factory=list)
    learned: FaultDetector | None = None
    blocks: dict[int, Window] = field(default_factory=dict)  # each alarm's block, by index
    cleared: list[Alarm] = field(default_factory=list)  # returned to normal (clearance.py)
    # each machine alarm's baseline before it (features), by (time_s, test): what its
    # return to normal is judged against, kept with the alarm for a restarted twin
    baselines: dict[tuple[float, str], np.ndarray] = field(default_factory=dict)

    def __iadd__(self, other: Step) -> Step:
        self.alarms += other.alarms
        self.requests += other.requests
        self.cleared += other.cleared
        self.learned = other.learned or self.learned
        self.blocks.update(other.blocks)
        self.baselines.update(other.baselines)
        return self


@dataclass
class _Open:
    """A window collecting blocks."""

    alarm: Alarm
    base: np.ndarray
    after: list[Window]
    sensor: tuple[str, str] | None = None
    sensor_window: Window | None = None  # the block whose rule named the sensor


class Decisions:
    """The decisions on block features, one block at a time (see the module docstring).

    Args:
        detector: a fitted detector.
        block_s: the blocks' length, s.
        post_s: the window after an alarm, s.
        trace: keep every block's statistics (a :class:`~drafttwin.diagnosis.detect.Detection`
            for the diagnosis page).
    """

    def __init__(self, detector: FaultDetector, block_s: float, *, post_s: float = POST_S,
                 trace: bool = False) -> None:  # fmt: skip
        self.detector, self.block_s = detector, block_s
        self.n_ref = detector.reference_blocks(block_s)
        self.post = max(1, int(round(post_s / block_s)))
        self.state = CusumState(detector, self.n_ref, block_s)
        self.clearance = Clearance(detector, block_s)
        self.recent: deque[Window] = deque(maxlen=self.post + self.n_ref + 2)
        self.open: _Open | None = None
        self.sensor_active: set[str] = set()
        self.alarms: list[Alarm] = []
        self.trace: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] | None = (
            [] if trace else None
        )
        self.times: list[float] = []

    @property
    def learned_blocks(self) -> int:
        """Blocks decided on so far (the reference windows included)."""
        return self.state.block

    def add(self, row: BlockRow) -> Step:
        """One block's features: the alarms it raised and the window it closed, if any."""
        x = row.features
        # blocks are counted from this detector's start, as its alarms and baseline are (a
        # machine that learned first has a block stream that started before it)
        here = Window(row.time_s, self.state.block, x, row.lost, row.run, row.stale)
        self.recent.append(here)
        raised = self.state.update(row.time_s, x, row.lost, row.run, row.stale, row.steady)
        self._record(here, raised)
        step = Step()
        if not row.steady:  # a start, a stop, a speed change: nothing judged (CusumState)
            return step
        sensor = {a.test for a in raised if a.direction == 0}
        fresh = [a for a in raised if a.direction != 0 or a.test not in self.sensor_active]
        self.sensor_active = sensor
        step.cleared = self.clearance.block(x, sensor)  # before this block's own alarms
        step.alarms += fresh
        if fresh:
            step.blocks[here.block] = here
        self.alarms += fresh
        for a in fresh:
            self._open_window(a)
            base = None if a.direction == 0 else self.state.baseline_at_alarm
            self.clearance.raised(a, base)
            if base is not None:
                step.baselines[(a.time_s, a.test)] = base.copy()
        if self.open is not None:
            if self.open.sensor is None and sensor:  # a sensor rule takes the window over
                a = next(a for a in raised if a.direction == 0)
                self.open.sensor, self.open.sensor_window = _sensor_of(a), here
            # a sensor window counts every block (a dropped channel's levels may be NaN)
            counted = self.open.sensor is not None or np.isfinite(x).all()
            if counted and here.time_s > self.open.alarm.time_s:
                self.open.after.append(here)
            if len(self.open.after) >= self.post:
                step.requests.append(self._request(self.open, complete=True))
                self.open = None
        return step

    def finish(self) -> Step:
        """The record's end: the open window's request with the blocks it has (at least
        :data:`MIN_BLOCKS`, else the blocks from the change estimate on)."""
        step = Step()
        if self.open is None:
            return step
        w, self.open = self.open, None
        if len(w.after) < MIN_BLOCKS and w.sensor is None:
            a = w.alarm
            w.after = [b for b in self.recent
                       if b.time_s > a.change_s and np.isfinite(b.row).all()
                       and (b.time_s <= a.time_s or b in w.after)]  # fmt: skip
        if w.after or w.sensor is not None:
            step.requests.append(self._request(w, complete=False))
        return step

    def _open_window(self, a: Alarm) -> None:
        if a.direction == 0:  # a sensor rule: it names its channel, a window sizes it
            if self.open is None:
                base = self.state.baseline_at_alarm
                self.open = _Open(a, np.zeros(len(FEATURES)) if base is None else base.copy(),
                                  [], _sensor_of(a), self.recent[-1])  # fmt: skip
            elif self.open.sensor is None:  # it explains the machine alarm's window
                self.open.sensor, self.open.sensor_window = _sensor_of(a), self.recent[-1]
            return
        if self.open is not None:  # one window at a time: the first alarm's
            return
        base = self.state.baseline_at_alarm
        assert base is not None
        self.open = _Open(a, base.copy(), [])
        # a sensor rule from the change estimate on (before the alarm) takes it over
        for w in self.recent:
            if a.change_s <= w.time_s and w.block <= a.block:
                s = self.detector.sensor_alarm(w.time_s, w.block, w.lost, w.run, w.stale,
                                               self.block_s)  # fmt: skip
                if s is not None:
                    self.open.sensor, self.open.sensor_window = _sensor_of(s), w
                    break

    def _request(self, w: _Open, complete: bool) -> RankRequest:
        after = w.after
        if after:
            t = np.array([b.time_s for b in after])
            blocks = np.array([b.block for b in after])
            dev = np.vstack([b.row for b in after]) - w.base
        else:
            t, blocks, dev = np.zeros(0), np.zeros(0, dtype=int), np.zeros((0, len(FEATURES)))
        return RankRequest(w.alarm, w.base, t, blocks, dev, self.block_s, complete, w.sensor,
                           w.sensor_window)  # fmt: skip

    def _record(self, here: Window, raised: list[Alarm]) -> None:
        self.times.append(here.time_s)
        if self.trace is None:
            return
        s = self.state
        ns = len(STREAMS)
        dev = np.full(len(FEATURES), np.nan) if s.deviation is None else s.deviation
        stat = np.zeros(ns) if s.statistic is None else s.statistic
        jump = s.jump_ratio if s.deviation is not None else np.zeros(ns)
        sensor = self.detector.sensor_ratio(here.lost, here.run, here.stale)
        self.trace.append((dev.copy(), stat.copy(), jump.copy(), sensor))

    def detection(self) -> Detection:
        """Every block's statistics so far (with ``trace``), and the alarms."""
        assert self.trace is not None, "a stream without trace keeps no statistics"
        n = len(self.trace)
        if n == 0:
            ns, nf = len(STREAMS), len(FEATURES)
            dev, stat, jump, sensor = (np.zeros((0, nf)), np.zeros((0, ns)), np.zeros((0, ns)),
                                       np.zeros((0, 2 * len(CHANNELS))))  # fmt: skip
        else:
            dev, stat, jump, sensor = (np.vstack(c) for c in zip(*self.trace, strict=True))
        det = Detection(np.array(self.times), dev, stat, list(self.alarms), jump=jump,
                        sensor=sensor)  # fmt: skip
        return det


def decide(
    detector: FaultDetector, f: BlockFeatures, *, post_s: float = POST_S, trace: bool = False
) -> tuple[Decisions, Step]:
    """The decisions over a record's block features (stored ones: no samples, so a sensor
    fault is not sized): every alarm and every window, as the stream makes them."""
    decisions = Decisions(detector, f.block_s, post_s=post_s, trace=trace)
    step = Step()
    lags, stale, steady = f.lags, f.stale_runs, f.steady_blocks
    for j in range(len(f.time_s)):
        step += decisions.add(BlockRow(j, float(f.time_s[j]), f.level[j], f.lost[j], f.run[j],
                                       lags[j], stale[j], bool(steady[j])))  # fmt: skip
    step += decisions.finish()
    return decisions, step


def _sensor_of(a: Alarm) -> tuple[str, str]:
    rule, channel = a.test.split("_", 1)
    return channel, "dropout" if rule == "lost" else "stuck"


class DiagnosisStream:
    """Rows of one machine in, alarms and windows to rank out (see the module docstring).

    Args:
        period_s: the rows' sample period, s.
        ratio: the rollers' kinematic speed ratios
            (:func:`~drafttwin.diagnosis.residuals.roller_ratio`).
        detector: a fitted detector (its block length is the blocks'); or ``None`` with a
            ``learner``: the stream learns first, then decides with what it learned.
        learner: the machine's :class:`~drafttwin.diagnosis.learning.Learner` (it outlives
            the stream: a run after a stop goes on learning).
        post_s: the window after an alarm, s.
        trace: keep every block's statistics and features (the diagnosis page).
        machine: a name carried by the requests (the live twin's machine).
    """

    def __init__(self, period_s: float, ratio: np.ndarray, *,
                 detector: FaultDetector | None = None, learner: Learner | None = None,
                 post_s: float = POST_S, trace: bool = False, machine: str = "") -> None:  # fmt: skip
        if detector is None and learner is None:
            raise ValueError("a stream needs a fitted detector or a learner")
        block_s = detector.block_s_ if detector is not None else _learning_block_s(learner)
        self.blocks = BlockStream(block_s, period_s, ratio)
        self.learner = None if detector is not None else learner
        self.post_s, self.trace, self.machine = post_s, trace, machine
        self.decisions: Decisions | None = None
        if detector is not None:
            self.decisions = Decisions(detector, self.blocks.block_s, post_s=post_s, trace=trace)
        self.rows: list[BlockRow] = []  # every block (offline: the record's features)
        self._carried: list[tuple[Alarm, np.ndarray | None]] = []  # watched once deciding
        # the recent samples a sensor fault is sized on: the window and what precedes it
        n_ref = (detector or FaultDetector()).reference_blocks(self.blocks.block_s)
        self._raw_span = (int(round(post_s / block_s)) + n_ref + 3) * self.blocks.per
        self._raw_t: deque[np.ndarray] = deque()
        self._raw_y: deque[np.ndarray] = deque()
        self._raw_n = 0

    @property
    def learning(self) -> bool:
        return self.decisions is None

    def keep_watching(self, alarm: Alarm, base: np.ndarray | None) -> None:
        """An alarm of an earlier run (a gap, a restarted twin) that is still active: its
        return to normal is judged in this run too, against ``base`` (the baseline it left;
        ``None`` for a sensor rule)."""
        if self.decisions is not None:
            self.decisions.clearance.raised(alarm, base)
        else:
            self._carried.append((alarm, base))

    def carried(self) -> list[tuple[Alarm, np.ndarray | None]]:
        """The active alarms a next run can go on watching
        (:meth:`~drafttwin.diagnosis.clearance.Clearance.carried`)."""
        if self.decisions is None:
            return list(self._carried)
        return self.decisions.clearance.carried()

    def push(self, time_s: np.ndarray, y: np.ndarray, yhat: np.ndarray) -> Step:
        """Rows ``(n,)`` times, ``(n, 5)`` measured and predicted."""
        self._remember(np.atleast_1d(time_s), np.atleast_2d(y))
        step = Step()
        for row in self.blocks.push(time_s, y, yhat):
            step += self.add_block(row)
        return step

    def finish(self) -> Step:
        """The record's (or the run's) end."""
        step = Step()
        for row in self.blocks.finish():
            step += self.add_block(row)
        if self.decisions is not None:
            step += self._with_samples(self.decisions.finish())
        return step

    def add_block(self, row: BlockRow) -> Step:
        """One block's features (from :attr:`blocks`, or from stored features)."""
        if self.trace:
            self.rows.append(row)
        if self.decisions is None:
            assert self.learner is not None
            learned = self.learner.add(row, self.blocks.block_s)
            if learned is not None:
                self.decisions = Decisions(learned, self.blocks.block_s, post_s=self.post_s,
                                           trace=self.trace)  # fmt: skip
                for alarm, base in self._carried:
                    self.decisions.clearance.raised(alarm, base)
                self._carried = []
            return Step(learned=learned)
        return self._with_samples(self.decisions.add(row))

    def _with_samples(self, step: Step) -> Step:
        step.requests = [_with_raw(r, self._raw(_last_time(r)), self.machine)
                         for r in step.requests]  # fmt: skip
        return step

    def _remember(self, t: np.ndarray, y: np.ndarray) -> None:
        self._raw_t.append(np.asarray(t, dtype=np.float64).copy())
        self._raw_y.append(np.asarray(y, dtype=np.float64).copy())
        self._raw_n += len(t)
        while self._raw_n - len(self._raw_t[0]) >= self._raw_span:
            self._raw_n -= len(self._raw_t.popleft())
            self._raw_y.popleft()

    def _raw(self, until_s: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The recent samples up to ``until_s`` (the request's last block): a record pushed
        at once holds samples far past the alarm's window, a live stream a few rows past its
        block; cut there, both size a sensor fault on the same samples."""
        if not self._raw_t:
            return np.zeros(0), np.zeros((0, len(CHANNELS)))
        t, y = np.concatenate(self._raw_t), np.vstack(self._raw_y)
        if until_s is not None:
            k = int(np.searchsorted(t, until_s, side="right"))
            t, y = t[:k], y[:k]
        return t[-self._raw_span :], y[-self._raw_span :]


def _learning_block_s(learner: Learner | None) -> float:
    """The block length a learning stream uses: its prior's, else the detector's default."""
    if learner is not None and learner.prior is not None:
        return float(learner.prior.block_s_)
    return BLOCK_S


def _last_time(r: RankRequest) -> float | None:
    """The end of the request's last block (``None``: a request without blocks)."""
    return float(np.max(r.time_s)) if len(r.time_s) else None


def _with_raw(r: RankRequest, raw: tuple[np.ndarray, np.ndarray], machine: str) -> RankRequest:
    if r.sensor is None:
        return replace(r, machine=machine)
    return replace(r, raw_time_s=raw[0], raw_y=raw[1], machine=machine)


__all__ = ["MIN_BLOCKS", "POST_S", "Decisions", "DiagnosisStream", "RankRequest", "Step",
           "Window", "decide"]  # fmt: skip
