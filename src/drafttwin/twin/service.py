"""The live twin service: sources -> per-machine hybrid -> store, page and metrics.

One asyncio loop runs every source and processes each sample as it arrives (the machine's
hybrid is a few hundred microseconds to a few milliseconds of CPU); a writer thread commits
the store; the page's WebSocket clients get each processed row. A machine whose source goes
silent for ``silent_s`` is marked (an event, its state on the page) and its held rows are
released; the others run on.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drafttwin.diagnosis.detect import FaultDetector
from drafttwin.diagnosis.stream import RankRequest, Step
from drafttwin.models.online import forecast_many
from drafttwin.sliver import StapleDiagram
from drafttwin.sliver.watch import SliverAlarm, SliverWatch
from drafttwin.twin.faultwatch import LiveFaultWatch, Locator, alarm_detail
from drafttwin.twin.live import Begun, MachineTwin
from drafttwin.twin.sources.base import Sample, Source
from drafttwin.twin.sources.mapping import MachineMap
from drafttwin.twin.store.baselines import Baseline, BaselineStore
from drafttwin.twin.store.db import EventRow, SampleRow, StoreWriter
from drafttwin.wire.identity import MachineIdentity

LATENCY_WINDOW = 20_000
"""Latencies kept for the percentiles (sample received -> stored and pushed)."""
HISTORY_ROWS = 3000
"""Rows per machine kept in memory for the page (30 s at 100 Hz)."""
SOURCES_STOP_S = 1.5
"""At a stop, how long the sources may take to close their connections."""
LOCATE_WAIT_S = 2.0
"""After a stop signal, how long the rankings still running may take to finish (stored; one
takes about a second in the warm worker). One that does not finish is kept in the store and
ranked when the twin starts again there (without a store: stored as not localised)."""
LOCATE_END_S = 60.0
"""At the end of a run that was not stopped (a replay ended, --duration): how long the
rankings may take (a worker still starting included)."""
SLIVER_SENSOR_M = 0.005
"""Averaging length of a delivery sensor (the plant's, docs/sliver.md), m: its ideal curve."""


@dataclass
class MachineState:
    """What the page and /api/status show for a machine."""

    twin: MachineTwin
    mapping: MachineMap
    source: str
    state: str = "connecting"
    received: int = 0
    dropped: int = 0
    skipped: int = 0  # already in the store (a restart resumed after them)
    last_wall: float = 0.0
    resume_after_us: int | None = None
    recent: deque[SampleRow] = field(default_factory=lambda: deque(maxlen=HISTORY_ROWS))
    alarms: deque[EventRow] = field(default_factory=lambda: deque(maxlen=200))
    watch: LiveFaultWatch | None = None  # the fault detector, when the model has one
    model_key: str = ""  # the model file (the locator's key for its diagnoser)
    model_sha256: str = ""
    identity: MachineIdentity | None = None  # who the machine is, when its source says
    baseline: Baseline | None = None  # what it learned (stored with its identity)
    prior: dict[str, Any] | None = None  # the detector file it learns on top of
    refused: str | None = None  # why a stored baseline was not used
    faults: int = 0
    last_fault: EventRow | None = None  # the latest alarm or its cause (status, hall page)
    sliver: SliverWatch | None = None  # the sliver channel's watch, once the source sends one
    sliver_busy: bool = False  # a check runs in the worker thread
    # source time -> received (wall clock), s: the transport's share of the latency, for
    # live sources (a replay's times are the file's)
    transport_s: deque[float] = field(default_factory=lambda: deque(maxlen=LATENCY_WINDOW))
    newest_source_s: float = math.nan  # the newest processed sample's source time

    def transport_ms(self) -> dict[str, float] | None:
        if not self.transport_s or self.source.startswith("replay"):
            return None
        lat = np.asarray(self.transport_s) * 1e3
        return {"p50": float(np.percentile(lat, 50)), "p99": float(np.percentile(lat, 99))}

    def data_age_s(self) -> float | None:
        """Wall clock minus the newest sample's source time (live sources only)."""
        if self.source.startswith("replay") or not math.isfinite(self.newest_source_s):
            return None
        return time.time() - self.newest_source_s


class TwinService:
    """Run ``twins`` fed by ``sources``; rows go to ``writer`` (if any) and subscribers."""

    def __init__(self, states: dict[str, MachineState], sources: Sequence[Source],
                 writer: StoreWriter | None = None, *, silent_s: float = 2.0) -> None:  # fmt: skip
        self.states, self.sources, self.writer = states, list(sources), writer
        self.silent_s = silent_s
        self.latency_s: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self.rows = 0
        self.subscribers: list[Callable[[str, list[SampleRow], list[EventRow]], None]] = []
        self.metrics: Any = None  # drafttwin.twin.web.metrics.Metrics when the page runs
        self.event_hooks: list[Callable[[EventRow], None]] = []
        self.started = time.monotonic()
        self.locator = Locator()
        self._sliver_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sliver")
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop = asyncio.Event()
        self._batch: list[Sample] = []
        self._scheduled = False
        self.baselines: BaselineStore | None = None  # where machines' baselines are kept
        self._stop_signal = False
        self._closed = False
        self.after_stop = 0  # samples a source delivered after the stop began (not processed)
        self._ranking: dict[
            int, tuple[MachineState, RankRequest, FaultDetector]
        ] = {}  # in the worker

    # ---- samples in ---------------------------------------------------------------------
    def on_sample(self, s: Sample) -> None:
        """Queue a sample; the samples that arrive in one turn of the event loop (one OPC UA
        publish, one tick of the machines) are processed together, one network pass for all
        machines that share a model (:func:`~drafttwin.models.online.forecast_many`)."""
        if self._closed:  # stopping: nothing after the signal beyond what was in flight
            self.after_stop += 1
            return
        self._batch.append(s)
        if self._scheduled:
            return
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:  # called outside a loop (a script): at once
            self._run_batch()
            return
        self._scheduled = True
        loop.call_soon(self._run_batch)

    def _run_batch(self) -> None:
        self._scheduled = False
        batch, self._batch = self._batch, []
        rnd: list[tuple[MachineState, Begun, float]] = []
        for s in batch:
            st = self.states.get(s.machine)
            if st is None:
                continue
            st.received += 1
            st.last_wall = time.monotonic()
            if st.state != "live":
                st.state = "live"
            if st.resume_after_us is not None and s.ts_us <= st.resume_after_us:
                st.skipped += 1  # stored before a restart: not again
                continue
            if any(r[0] is st for r in rnd):  # a second sample of a machine: finish the first
                self._finish(rnd)
                rnd = []
            if s.sliver is not None:
                self._sliver(st, s.sliver)
            rows, begun = st.twin.receive_deferred(s.ts_us, s.seq, s.values, s.setpoint,
                                                   s.received, s.motor)  # fmt: skip
            self._out(st, rows, s.received)
            if begun is not None:
                rnd.append((st, begun, s.received))
        self._finish(rnd)

    def _finish(self, rnd: list[tuple[MachineState, Begun, float]]) -> None:
        if not rnd:
            return
        twins = forecast_many([b.predictor for _, b, _ in rnd], [b.ts_us / 1e6 for _, b, _ in rnd])
        for (st, b, received), twin in zip(rnd, twins, strict=True):
            self._out(st, [st.twin.end(b, twin)], received)

    def _out(self, st: MachineState, rows: list[SampleRow], received: float | None) -> None:
        events, st.twin.events = st.twin.events, []
        for ev in events:
            self._event(st, ev)
        if not rows:
            if events:
                for push in self.subscribers:
                    push(st.twin.name, [], events)
            return
        for row in rows:
            st.recent.append(row)
            if self.writer is not None:
                self.writer.put(row)
        if st.watch is not None:
            events += self._watch_rows(st, rows)
        for push in self.subscribers:
            push(st.twin.name, rows, events)
        self.rows += len(rows)
        st.newest_source_s = float(np.fmax(st.newest_source_s, rows[-1].ts_us * 1e-6))
        if received is not None and math.isfinite(received):  # NaN: recovered, not live
            lat = time.perf_counter() - received
            # the wall time it arrived, minus the time its source gave it
            st.transport_s.append(time.time() - lat - rows[-1].ts_us * 1e-6)
            self.latency_s.append(lat)
            if self.metrics is not None:
                self.metrics.observe(st.twin.name, len(rows), lat)

    # ---- the sliver -----------------------------------------------------------------------
    def _sliver(self, st: MachineState, readings: tuple[np.ndarray, ...]) -> None:
        """Feed the machine's sliver watch; its checks (a spectrogram of the last 100 m every
        50 m) run in a worker thread, so the samples keep their pace."""
        if st.sliver is None:
            st.sliver = SliverWatch(st.twin.train, StapleDiagram.preset("cotton"),
                                    sensor_length_m=SLIVER_SENSOR_M, checks_now=False)  # fmt: skip
        st.sliver.push(*readings)
        if st.sliver.due() and not st.sliver_busy:
            st.sliver_busy = True
            watch = st.sliver

            def checked(fut: Any) -> None:
                alarms = [] if fut.exception() is not None else fut.result()
                if self._loop is not None and self._loop.is_running():
                    self._loop.call_soon_threadsafe(self._sliver_alarms, st, alarms)
                else:
                    self._sliver_alarms(st, alarms)

            self._sliver_pool.submit(watch.check).add_done_callback(checked)

    def _sliver_alarms(self, st: MachineState, alarms: list[SliverAlarm]) -> None:
        st.sliver_busy = False
        for a in alarms:
            assert st.sliver is not None
            ev = EventRow(st.twin.name, "sliver-chimney", int(round(a.time_s * 1e6)),
                          st.sliver.text(a))  # fmt: skip
            self._event(st, ev)
            for push in self.subscribers:
                push(st.twin.name, [], [ev])

    # ---- faults -------------------------------------------------------------------------
    def _watch_rows(self, st: MachineState, rows: list[SampleRow]) -> list[EventRow]:
        """Feed the machine's diagnosis; alarms become events at once, windows are ranked in
        the worker, a learning state that ends stores the machine's baseline."""
        assert st.watch is not None
        out = []
        for row in rows:
            out += self._took(st, st.watch.add(row), row.ts_us)
        return out

    def _took(self, st: MachineState, step: Step, ts_us: int,
              judge: FaultDetector | None = None) -> list[EventRow]:  # fmt: skip
        """What a machine's diagnosis brought: its learning's end, alarms, windows to rank
        (with ``judge``, the detector that raised them, or the machine's present one)."""
        out = []
        if step.learned is not None:
            out.append(self._learned(st, step.learned, ts_us))
        out += self._fault_events(st, step)
        for req in step.requests:
            self._locate(st, req, judge)
        return out

    def _fault_events(self, st: MachineState, step: Step) -> list[EventRow]:
        assert st.watch is not None
        out = []
        for a in step.alarms:
            st.faults += 1
            note = f"probable cause after {st.watch.post_s:g} s"
            if a.direction == 0:  # a sensor rule: its channel is the cause, sized later
                ev = EventRow(st.twin.name, "sensor-fault", int(round(a.time_s * 1e6)),
                              alarm_detail(a, [st.watch.sensor_cause(a, step)], note))  # fmt: skip
            else:
                ev = EventRow(st.twin.name, "fault", int(round(a.time_s * 1e6)),
                              alarm_detail(a, note=note))  # fmt: skip
            self._event(st, ev)
            out.append(ev)
        return out

    def _learned(self, st: MachineState, detector: FaultDetector, ts_us: int) -> EventRow:
        """A machine finished learning: its baseline, stored with its identity."""
        assert st.watch is not None
        start = st.watch.learn_from_s if st.watch.learn_from_s is not None else ts_us / 1e6
        st.baseline = Baseline(st.twin.name, detector, st.model_sha256, st.identity,
                               st.watch.learn_s, start, ts_us / 1e6, st.prior)  # fmt: skip
        where = ""
        if self.baselines is not None:
            try:
                where = f"; stored in {self.baselines.save(st.baseline)}"
                self.baselines.forget_learning(st.twin.name)
            except OSError as exc:
                where = f"; not stored ({type(exc).__name__}: {exc})"
        who = f" ({st.identity})" if st.identity is not None else ""
        ev = EventRow(st.twin.name, "learned", ts_us,
                      f"learned its healthy state{who} over {st.watch.learn_s:g} s of running"
                      + ("" if st.prior is None else f" on top of {st.prior['file']}") + where
                      + ("" if detector.lags_watched else "; angle lags not watched"))  # fmt: skip
        self._event(st, ev)
        return ev

    def announce(self, st: MachineState) -> None:
        """At the start: what the machine's detector does (learns, or watches with the
        baseline the store kept), and a stored baseline refused, by name."""
        w = st.watch
        assert w is not None
        now = int(time.time() * 1e6)
        if st.refused is not None:
            self._event(st, EventRow(st.twin.name, "baseline-refused", now,
                                     f"stored baseline not used: {st.refused}"))  # fmt: skip
        if w.learning:
            prior = "" if st.prior is None else f", on top of {st.prior['file']}"
            done = w.learner.learned_s if w.learner is not None else 0.0
            kept = f" ({done:g} s of it learned before the twin restarted)" if done else ""
            text = (f"learning its healthy state: {w.learn_s:g} s of running{prior}{kept}; no "
                    "fault alarm meanwhile")  # fmt: skip
            self._event(st, EventRow(st.twin.name, "learning", now, text))
        elif st.baseline is not None:
            b = st.baseline
            who = "" if b.identity is None else f" on {b.identity}"
            self._event(st, EventRow(st.twin.name, "baseline", now,
                                     f"watching with the baseline learned{who} over "
                                     f"{b.learned_s:g} s of running"))  # fmt: skip
        else:
            self._judged_as_is(st)

    def _judged_as_is(self, st: MachineState) -> None:
        """No learning (``--learn 0``): the detector file judges the machine as it is; said
        by name when it was fitted on other machines, or nobody knows."""
        if st.prior is None or st.baseline is not None or st.watch is None or st.watch.learning:
            return
        made = st.prior.get("machines") or []
        on = ", ".join(made) if made else "machines its records do not name"
        if st.identity is not None and st.identity.serial in made:
            kind, text = "baseline", f"judged by {st.prior['file']}, fitted on this machine"
        elif st.identity is None and not st.source.startswith("replay"):
            return  # a live source says who the machine is once connected (identify)
        elif st.identity is None:
            kind = "detector-foreign"
            text = (f"judged by {st.prior['file']} (fitted on {on}); the source does not say "
                    "which machine this is")  # fmt: skip
        else:
            kind = "detector-foreign"
            text = (f"judged by {st.prior['file']}, fitted on {on}, not on this machine "
                    f"({st.identity}): let it learn its own (leave out --learn 0)")  # fmt: skip
        self._event(st, EventRow(st.twin.name, kind, int(time.time() * 1e6), text))

    def relearn(self, machine: str, why: str = "operator's command") -> bool:
        """Forget a machine's baseline and learn again (after maintenance); False: no such
        machine with a detector."""
        st = self.states.get(machine)
        if st is None or st.watch is None:
            return False
        judge = st.watch.detector  # the windows of the old run were raised by it
        self._took(st, st.watch.relearn(), int(time.time() * 1e6), judge)
        st.baseline = None
        if self.baselines is not None:
            self.baselines.forget(machine)
        ev = EventRow(machine, "learning", int(time.time() * 1e6),
                      f"learning its healthy state again ({why}): {st.watch.learn_s:g} s of "
                      "running, no fault alarm meanwhile")  # fmt: skip
        self._event(st, ev)
        for push in self.subscribers:
            push(machine, [], [ev])
        return True

    def identify(self, machine: str, identity: MachineIdentity) -> None:
        """The source says who the machine is: a baseline learned on another machine is
        refused by name, and the machine learns its own."""
        st = self.states.get(machine)
        if st is None:
            return
        before, st.identity = st.identity, identity
        if before == identity:
            return
        learned = st.baseline.identity if st.baseline is not None else None
        if st.baseline is not None and learned is not None and learned != identity:
            self.relearn(machine, f"its baseline was learned on {learned}, the machine now says "
                                  f"{identity}")  # fmt: skip
        elif before is not None and st.watch is not None and st.watch.learning:
            self.relearn(machine, f"it was learning {before}, the machine now says {identity}")
        elif st.baseline is not None and learned is None:
            st.baseline.identity = identity  # learned before the source named it: it is this one
            if self.baselines is not None:
                self.baselines.save(st.baseline)
        else:
            self._judged_as_is(st)

    def _locate(self, st: MachineState, req: RankRequest, judge: FaultDetector | None = None,
                post_s: float | None = None, kept: Path | None = None) -> None:  # fmt: skip
        """Rank a window in the worker and store the cause (``judge``: the detector that raised
        it, default the machine's; ``kept``: the file of a window a stopped twin left, removed
        once ranked)."""

        def done(r: RankRequest, causes: list[dict[str, Any]] | None, error: str | None) -> None:
            note = None if causes is not None else f"not localised ({error})"
            if kept is not None:
                note = (note + "; " if note else "") + "ranked after the twin restarted"
                kept.unlink(missing_ok=True)
            ev = EventRow(st.twin.name, "fault-cause", int(round(r.alarm.time_s * 1e6)),
                          alarm_detail(r.alarm, causes, note))  # fmt: skip
            if self._loop is not None and self._loop.is_running():
                self._loop.call_soon_threadsafe(self._cause, st, ev, causes)
            else:
                self._cause(st, ev, causes)

        det = judge if judge is not None else st.watch.detector if st.watch is not None else None
        if det is None:
            done(req, None, "the machine is learning again")
            return
        key = id(req)
        self._ranking[key] = (st, req, det)

        def once(r: RankRequest, causes: list[dict[str, Any]] | None, error: str | None) -> None:
            if self._ranking.pop(key, None) is not None:  # (settled at the stop: stored then)
                done(r, causes, error)

        post = post_s if post_s is not None else st.watch.post_s if st.watch else 0.0
        if not self.locator.submit(st.model_key, det, post, req, once):
            once(req, None, "the locator is busy")

    def _cause(self, st: MachineState, ev: EventRow, causes: list[dict[str, Any]] | None) -> None:
        self._event(st, ev)
        if self.metrics is not None and hasattr(self.metrics, "cause"):
            top = causes[0] if causes else None
            self.metrics.cause(ev.machine, "none" if top is None else
                               f"{top['element']}:{top['kind']}")  # fmt: skip
        for push in self.subscribers:
            push(st.twin.name, [], [ev])

    async def _settle_faults(self) -> None:
        """At the end: rank what each open window has, wait for the rankings running
        (:data:`LOCATE_WAIT_S` after a stop signal, else :data:`LOCATE_END_S`); one not done
        then is kept for the next twin, or stored as not localised."""
        for st in self.states.values():
            if st.watch is not None:
                last = st.twin.last_us if st.twin.last_us else int(time.time() * 1e6)
                self._took(st, st.watch.flush(), last)
        start = time.monotonic()
        while self._ranking:
            budget = LOCATE_WAIT_S if self._stop_signal else LOCATE_END_S
            if time.monotonic() - start >= budget:
                break
            await asyncio.sleep(0.02)
        await asyncio.sleep(0)  # the callbacks scheduled from the worker's thread
        for key, (st, req, det) in list(self._ranking.items()):  # an alarm is never left
            self._ranking.pop(key, None)  # without its cause, or the word why and when
            why = "not localised (the twin stopped before its ranking finished)"
            if self.baselines is not None and st.watch is not None:
                self.baselines.save_pending(st.twin.name, req, det, st.watch.post_s)
                why = ("probable cause pending: the twin stopped before its ranking finished; "
                       "ranked when it starts again on this store")  # fmt: skip
            self._cause(st, EventRow(st.twin.name, "fault-cause", int(round(req.alarm.time_s * 1e6)),
                                     alarm_detail(req.alarm, None, why)), None)  # fmt: skip
        self._keep_learning()
        self.locator.close()
        self._sliver_pool.shutdown(wait=True, cancel_futures=True)

    def _keep_learning(self) -> None:
        """Each learning machine's blocks so far, kept for the next twin on this store."""
        if self.baselines is None:
            return
        for st in self.states.values():
            w = st.watch
            if w is not None and w.learner is not None and w.learner.blocks:
                with contextlib.suppress(OSError):
                    self.baselines.save_learning(st.twin.name, w.learner, st.identity,
                                                 st.model_sha256, w.learn_from_s)  # fmt: skip

    def _resume_pending(self) -> None:
        """Rank the windows a stopped twin left (their alarms are stored already)."""
        if self.baselines is None:
            return
        for st in self.states.values():
            if st.watch is None:
                continue
            for path, req, det, post_s in self.baselines.pending(st.twin.name):
                self._locate(st, req, det, post_s, kept=path)

    def report(self, machine: str, kind: str, detail: str, count: int = 1) -> None:
        """A source's state change, or ``count`` dropped payloads."""
        st = self.states.get(machine)
        if st is None:
            return
        if kind == "identity":  # the source says who the machine is
            self._run_batch()  # the samples before it are the machine it was
            try:
                identity = MachineIdentity.from_dict(json.loads(detail))
            except ValueError:
                identity = None
            if identity is not None and identity != st.identity:
                self._event(st, EventRow(machine, "identity", int(time.time() * 1e6),
                                         f"the machine is {identity} ({identity.model})"))  # fmt: skip
                self.identify(machine, identity)
            return
        if kind.startswith("source-"):
            st.state = kind.removeprefix("source-")
        if kind == "dropped":
            before, st.dropped = st.dropped, st.dropped + count
            if self.metrics is not None:
                self.metrics.dropped(machine, count)
            if before >= 100 and before // 1000 == st.dropped // 1000:
                return  # a flood: counted, one event per 1000
        self._event(st, EventRow(machine, kind, int(time.time() * 1e6), detail[:500]))

    def _event(self, st: MachineState, ev: EventRow) -> None:
        st.alarms.append(ev)
        if ev.kind in ("fault", "fault-cause", "sensor-fault"):
            st.last_fault = ev
        for hook in self.event_hooks:
            hook(ev)
        if self.writer is not None:
            self.writer.put(ev)

    # ---- running ------------------------------------------------------------------------
    async def _watch(self) -> None:
        """Mark silent machines and release what their reorder buffers hold."""
        while not self._stop.is_set():
            await asyncio.sleep(min(0.5, self.silent_s / 2))
            now = time.monotonic()
            for st in self.states.values():
                quiet = st.last_wall and now - st.last_wall > self.silent_s
                if quiet and st.state == "live":
                    st.state = "silent"
                    self._event(st, EventRow(st.twin.name, "silent", int(time.time() * 1e6),
                                             f"no sample for {self.silent_s:g} s"))  # fmt: skip
                    self._out(st, st.twin.flush(), None)

    async def run(self, *, duration_s: float | None = None, max_rows: int | None = None) -> None:
        """Run until every source ended, ``duration_s`` passed or ``max_rows`` were processed."""
        self._loop = asyncio.get_running_loop()
        self.locator.warm()  # a worker process: the first alarm must not wait for its start
        self._resume_pending()
        tasks = [asyncio.create_task(src.run(self.on_sample, self.report)) for src in self.sources]
        watch = asyncio.create_task(self._watch())
        deadline = math.inf if duration_s is None else time.monotonic() + duration_s
        try:
            while time.monotonic() < deadline and not self._stop.is_set():
                if max_rows is not None and self.rows >= max_rows:
                    break
                if all(t.done() for t in tasks):
                    for t in tasks:
                        if t.exception() is not None:
                            raise t.exception()  # type: ignore[misc]
                    break
                await asyncio.sleep(0.05)
        except asyncio.CancelledError:  # a stop signal: the rankings get a short while
            self._stop_signal = True
            raise
        finally:
            # the end runs to its end: a second signal meanwhile only shortens the wait for
            # the rankings (an alarm's cause is stored, or kept for the next start)
            ending = asyncio.ensure_future(self._end(tasks, watch))
            late_cancel = False
            while not ending.done():
                try:
                    await asyncio.shield(ending)
                except asyncio.CancelledError:
                    self._stop_signal = late_cancel = True
            ending.result()
            if late_cancel:  # the caller cancelled during the end: it is told so
                raise asyncio.CancelledError

    async def _end(self, tasks: list[asyncio.Task[None]], watch: asyncio.Task[None]) -> None:
        self._stop.set()
        self._closed = True  # what the sources deliver from now on is not processed
        for t in [*tasks, watch]:
            t.cancel()
        # a client library stuck in its own clean-up must not hold the twin's shutdown
        await asyncio.wait([*tasks, watch], timeout=SOURCES_STOP_S)
        self._run_batch()
        for st in self.states.values():
            self._out(st, st.twin.flush(), None)
        await self._settle_faults()

    def stop(self) -> None:
        """Stop as a signal does (the rankings still running get a short while)."""
        self._stop_signal = True
        self._stop.set()

    # ---- figures ------------------------------------------------------------------------
    def latency_ms(self) -> dict[str, float | None]:
        if not self.latency_s:
            return {"p50": None, "p99": None, "max": None}
        lat = np.asarray(self.latency_s) * 1e3
        return {"p50": float(np.percentile(lat, 50)), "p99": float(np.percentile(lat, 99)),
                "max": float(lat.max())}  # fmt: skip

    def status(self) -> dict[str, Any]:
        return {
            "uptime_s": time.monotonic() - self.started,
            "rows": self.rows,
            "latency_ms": self.latency_ms(),
            "store": None if self.writer is None else {
                "committed": self.writer.committed, "dropped": self.writer.dropped,
                "commit_ms": self.writer.commit_s * 1e3},
            "machines": {name: {"state": st.state, "received": st.received,
                                "processed": st.twin.n_rows, "dropped": st.dropped,
                                "skipped": st.skipped, "late": st.twin.reorder.late,
                                "duplicate": st.twin.reorder.duplicate,
                                "spikes_rejected": st.twin.filter.rejected,
                                "source": st.source, "fault_alarms": st.faults,
                                "fault_detector": st.watch is not None,
                                "fault_motor": st.watch is not None and st.watch.has_motor,
                                "detector": detector_state(st),
                                "identity": None if st.identity is None else st.identity.to_dict(),
                                "last_fault": _fault(st.last_fault),
                                "sliver": None if st.sliver is None else st.sliver.summary(),
                                "transport_ms": st.transport_ms(),
                                "data_age_s": st.data_age_s()}
                         for name, st in self.states.items()},
        }  # fmt: skip


def detector_state(st: MachineState) -> dict[str, Any]:
    """A machine's fault detector as status shows it: ``none``, ``learning`` (how far, how
    long still) or ``watching`` (its baseline: when and over how long it was learned, the
    identity it was learned on, the prior it was combined with)."""
    w = st.watch
    if w is None:
        return {"state": "none"}
    out: dict[str, Any] = {"state": "learning" if w.learning else "watching",
                           "learn_s": w.learn_s, "prior": None if st.prior is None else st.prior["file"]}  # fmt: skip
    if w.learning:
        out.update({"progress": round(w.learn_progress, 4), "left_s": round(w.learn_left_s, 1)})
    elif st.baseline is not None:
        out["baseline"] = st.baseline.summary()
    return out


def _fault(ev: EventRow | None) -> dict[str, Any] | None:
    """An alarm event as status shows it: its kind and time, and its detail parsed."""
    if ev is None:
        return None
    try:
        detail = json.loads(ev.detail)
    except ValueError:
        detail = {"text": ev.detail}
    return {"kind": ev.kind, "time": ev.ts_us / 1e6, **detail}


__all__ = ["MachineState", "TwinService"]
