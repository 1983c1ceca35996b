"""The live twin service: sources -> per-machine hybrid -> store, page and metrics.

One asyncio loop runs every source and processes each sample as it arrives (the machine's
hybrid is a few hundred microseconds to a few milliseconds of CPU); a writer thread commits
the store; the page's WebSocket clients get each processed row. A machine whose source goes
silent for ``silent_s`` is marked (an event, its state on the page) and its held rows are
released; the others run on.
"""

from __future__ import annotations

import asyncio
import gc
import json
import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from drafttwin.models.online import forecast_many
from drafttwin.sliver.levelwatch import SEARCH_MM, WINDOW_M
from drafttwin.twin.faults import FaultDesk
from drafttwin.twin.live import Begun
from drafttwin.twin.sliverdesk import SliverDesk
from drafttwin.twin.sources.base import Sample, SliverBatch, Source
from drafttwin.twin.state import (
    ALARM_KINDS,
    LATENCY_WINDOW,
    MachineState,
    detector_state,
    fault_summary,
)
from drafttwin.twin.store.db import EventRow, SampleRow, StoreWriter
from drafttwin.wire.identity import MachineIdentity

SOURCES_STOP_S = 1.5
"""At a stop, how long the sources may take to close their connections."""
WAITING_S = 10.0
"""A source connected this long without a sample of a machine: the twin says so once (the
machine is 'waiting', not 'live'; a wrong name in the mapping looked live at 0 samples)."""


class TwinService:
    """Run ``twins`` fed by ``sources``; rows go to ``writer`` (if any) and subscribers."""

    def __init__(self, states: dict[str, MachineState], sources: Sequence[Source],
                 writer: StoreWriter | None = None, *, silent_s: float = 2.0,
                 level_window_m: float = WINDOW_M,
                 level_search_mm: float = SEARCH_MM) -> None:  # fmt: skip
        self.states, self.sources, self.writer = states, list(sources), writer
        self.silent_s = silent_s
        self.latency_s: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self.rows = 0
        self.subscribers: list[Callable[[str, list[SampleRow], list[EventRow]], None]] = []
        self.metrics: Any = None  # drafttwin.twin.web.metrics.Metrics when the page runs
        self.event_hooks: list[Callable[[EventRow], None]] = []
        self.started = time.monotonic()
        self.slivers = SliverDesk(self, level_window_m, level_search_mm)
        self.loop: asyncio.AbstractEventLoop | None = None
        self._stop = asyncio.Event()
        self._batch: list[Sample] = []
        self._scheduled = False
        self.stop_signalled = False
        self._closed = False
        self.max_rows: int | None = None  # samples to take (run's max_rows), None: all
        self.taken = 0  # samples taken so far
        self.after_stop = 0  # samples a source delivered after the stop began (not processed)
        self.faults = FaultDesk(self)
        self.slivers.lines_learned = self.faults.sliver_lines

    @property
    def locator(self) -> Any:
        return self.faults.locator

    @property
    def book(self) -> Any:
        return self.faults.book

    @property
    def baselines(self) -> Any:
        return self.faults.baselines

    @baselines.setter
    def baselines(self, store: Any) -> None:
        self.faults.baselines = store

    def relearn(self, machine: str, why: str = "operator's command") -> bool:
        """Forget a machine's baseline and learn again (after maintenance)."""
        return self.faults.relearn(machine, why)

    def announce(self, st: MachineState) -> None:
        self.faults.announce(st)

    # ---- samples in ---------------------------------------------------------------------
    def on_sample(self, s: Sample | SliverBatch) -> None:
        """Queue a sample; the samples that arrive in one turn of the event loop (one OPC UA
        publish, one tick of the machines) are processed together, one network pass for all
        machines that share a model (:func:`~drafttwin.models.online.forecast_many`). A batch
        of sliver readings goes to the sliver desk at once."""
        if self._closed:  # stopping: nothing after the signal beyond what was in flight
            self.after_stop += 1
            return
        if self.max_rows is not None and not isinstance(s, SliverBatch):
            if self.taken >= self.max_rows:  # --max-samples: a replay at full speed hands
                self.after_stop += 1  # thousands in one turn of the loop; stop at the count
                self._stop.set()
                return
            self.taken += 1
        if isinstance(s, SliverBatch):
            st = self.states.get(s.machine)
            if st is not None:
                self.slivers.batch(st, s)
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
        in_round: set[str] = set()  # the machines in rnd (a set: 100 machines a tick)
        for s in batch:
            st = self.states.get(s.machine)
            if st is None:
                continue
            st.received += 1
            st.last_wall = time.monotonic()
            if st.state != "live":
                st.state, st.waiting_since = "live", None
            if st.resume_after_us is not None and s.ts_us <= st.resume_after_us:
                st.skipped += 1  # stored before a restart: not again
                continue
            if s.machine in in_round:  # a second sample of a machine: finish the first
                self._finish(rnd)
                rnd, in_round = [], set()
            if s.sliver is not None:
                self.slivers.batch(st, s.sliver)
            rows, begun = st.twin.receive_deferred(s.ts_us, s.seq, s.values, s.setpoint,
                                                   s.received, s.motor)  # fmt: skip
            self._out(st, rows, s.received)
            if begun is not None:
                rnd.append((st, begun, s.received))
                in_round.add(s.machine)
        self._finish(rnd)

    def _finish(self, rnd: list[tuple[MachineState, Begun, float]]) -> None:
        if not rnd:
            return
        twins = forecast_many([b.predictor for _, b, _ in rnd], [b.ts_us / 1e6 for _, b, _ in rnd],
                              [b.physics for _, b, _ in rnd])  # fmt: skip
        for (st, b, received), twin in zip(rnd, twins, strict=True):
            self._out(st, [st.twin.end(b, twin)], received)

    def _out(self, st: MachineState, rows: list[SampleRow], received: float | None) -> None:
        events, st.twin.events = st.twin.events, []
        for ev in events:
            self.event(st, ev)
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
            events += self.faults.watch_rows(st, rows)
        for push in self.subscribers:
            push(st.twin.name, rows, events)
        self.rows += len(rows)
        newest = rows[-1].ts_us * 1e-6
        if not st.newest_source_s >= newest:  # NaN (none yet) or older
            st.newest_source_s = newest
        if received is not None and math.isfinite(received):  # NaN: recovered, not live
            lat = time.perf_counter() - received
            # the wall time it arrived, minus the time its source gave it
            st.transport_s.append(time.time() - lat - rows[-1].ts_us * 1e-6)
            self.latency_s.append(lat)
            if self.metrics is not None:
                self.metrics.observe(st.twin.name, len(rows), lat)

    def report(self, machine: str, kind: str, detail: str, count: int = 1) -> None:
        """A source's state change, or ``count`` dropped payloads."""
        st = self.states.get(machine)
        if st is None:
            return
        if kind == "leveller":  # the source describes its sliver and leveller
            self.slivers.describe(st, detail)
            return
        if kind == "identity":  # the source says who the machine is
            self._run_batch()  # the samples before it are the machine it was
            try:
                identity = MachineIdentity.from_dict(json.loads(detail))
            except ValueError:
                identity = None
            if identity is not None and identity != st.identity:
                self.event(st, EventRow(machine, "identity", int(time.time() * 1e6),
                                         f"the machine is {identity} ({identity.model})"))  # fmt: skip
                self.faults.identify(machine, identity)
            return
        if kind.startswith("source-"):
            st.state = kind.removeprefix("source-")
            if st.state == "live" and st.last_wall == 0.0:  # connected, nothing of it yet
                st.state, st.waiting_since = "waiting", time.monotonic()
        if kind == "dropped":
            before, st.dropped = st.dropped, st.dropped + count
            if self.metrics is not None:
                self.metrics.dropped(machine, count)
            if before >= 100 and before // 1000 == st.dropped // 1000:
                return  # a flood: counted, one event per 1000
        self.event(st, EventRow(machine, kind, int(time.time() * 1e6), detail[:500]))

    def event(self, st: MachineState, ev: EventRow) -> None:
        (st.alarms if ev.kind in ALARM_KINDS else st.events).append(ev)
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
                waited = st.waiting_since is not None and now - st.waiting_since > WAITING_S
                if waited and st.state == "waiting":
                    st.waiting_since = None  # said once per connection
                    self.event(st, EventRow(st.twin.name, "no-samples", int(time.time() * 1e6),
                                            f"connected, but no sample of machine "
                                            f"'{st.twin.name}' in {WAITING_S:g} s: does the "
                                            "source name it so? (a mapping: --mapping; one "
                                            "machine: ?machine=NAME in --source)"))  # fmt: skip
                quiet = st.last_wall and now - st.last_wall > self.silent_s
                if quiet and st.state == "live":
                    st.state = "silent"
                    self.event(st, EventRow(st.twin.name, "silent", int(time.time() * 1e6),
                                             f"no sample for {self.silent_s:g} s"))  # fmt: skip
                    self._out(st, st.twin.flush(), None)

    async def run(self, *, duration_s: float | None = None, max_rows: int | None = None) -> None:
        """Run until every source ended, ``duration_s`` passed or ``max_rows`` were processed."""
        self.loop = asyncio.get_running_loop()
        self.max_rows = max_rows
        self.locator.warm()  # a worker process: the first alarm must not wait for its start
        self.faults.resume_pending()
        tasks = [asyncio.create_task(src.run(self.on_sample, self.report)) for src in self.sources]
        watch = asyncio.create_task(self._watch())
        deadline = math.inf if duration_s is None else time.monotonic() + duration_s
        # what exists now (models, trains, kernels, the libraries) lives as long as the twin:
        # out of the collector's full passes, which walked it in one 200-400 ms pause every
        # few seconds at 100 machines (p99 9 -> 23 ms, measured); given back at the end
        gc.freeze()
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
            self.stop_signalled = True
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
                    self.stop_signalled = late_cancel = True
            gc.unfreeze()
            ending.result()
            if late_cancel:  # the caller cancelled during the end: it is told so
                raise asyncio.CancelledError

    async def _end(self, tasks: list[asyncio.Task[None]], watch: asyncio.Task[None]) -> None:
        self._stop.set()
        for t in [*tasks, watch]:
            t.cancel()
        # a client library stuck in its own clean-up must not hold the twin's shutdown; the
        # samples a source had received are handed over as it closes (and processed)
        await asyncio.wait([*tasks, watch], timeout=SOURCES_STOP_S)
        await asyncio.sleep(0)  # what a network thread queued for the loop before
        self._closed = True  # what the sources deliver from now on is not processed
        self._run_batch()
        for st in self.states.values():
            self._out(st, st.twin.flush(), None)
        await self.faults.settle()
        await self.slivers.settle()

    def stop(self) -> None:
        """Stop as a signal does (the rankings still running get a short while)."""
        self.stop_signalled = True
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
                                "last_fault": fault_summary(st.last_fault),
                                "active_alarms": [a.to_dict() for a in self.book.retained(name)],
                                **self.slivers.status(st),
                                "transport_ms": st.transport_ms(),
                                "data_age_s": st.data_age_s()}
                         for name, st in self.states.items()},
        }  # fmt: skip


__all__ = ["MachineState", "TwinService", "detector_state"]
