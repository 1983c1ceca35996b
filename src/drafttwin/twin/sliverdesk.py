"""The twin's sliver desk: each machine's sliver readings watched as they arrive (running count
and CV, a spectrogram of the last 100 m every 50 m, chimneys named with their element:
:class:`~drafttwin.sliver.watch.SliverWatch`) and its leveller's action point recommended
from every window of delivered sliver (:class:`~drafttwin.sliver.levelwatch.LevelWatch`, the
function behind ``drafttwin sliver level``). The same for a replayed record and a served
plant (``plant serve --sliver``): the live path computes with the offline functions.

Both run in worker threads, so the samples keep their pace: a spectrogram takes a fraction of
a second, a 300-m window of the leveller a few seconds. At a stop by signal the leveller's
window in progress is abandoned (SIGTERM ends the twin within 5 s); a replay that ends or a
run of fixed duration waits for it. The twin recommends; it never writes a setting.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, Protocol

from drafttwin.errors import DrafttwinError
from drafttwin.sliver import StapleDiagram
from drafttwin.sliver.levelwatch import SEARCH_MM, WINDOW_M, LevelContext, LevelWatch
from drafttwin.sliver.reference import SAME_CHANNEL
from drafttwin.sliver.watch import SliverAlarm, SliverWatch
from drafttwin.twin.state import MachineState
from drafttwin.twin.store.db import EventRow
from drafttwin.wire.sliver import SliverBatch, parse_description

SIGNAL_POLL_S = 0.2
"""How often a natural end that waits for the leveller's window looks for a stop signal."""
SLIVER_SENSOR_M = 0.005
"""Averaging length of a delivery sensor (the plant's, docs/sliver.md), m: its ideal curve."""


class DaemonWorker:
    """One daemon thread that runs submitted calls in turn (a one-worker executor whose
    thread the interpreter does not wait for at exit). A leveller's window computes for
    seconds; a ThreadPoolExecutor's thread is joined at exit, so a signal that came while one
    ran (at a replay's end) held the twin for up to 9 s after its summary."""

    def __init__(self, name: str) -> None:
        self._jobs: queue.SimpleQueue[tuple[Future[Any], Callable[..., Any], tuple[Any, ...]] | None] = queue.SimpleQueue()  # fmt: skip
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future[Any]:
        fut: Future[Any] = Future()
        self._jobs.put((fut, fn, args))
        return fut

    def _run(self) -> None:
        while (job := self._jobs.get()) is not None:
            fut, fn, args = job
            if not fut.set_running_or_notify_cancel():
                continue
            try:
                fut.set_result(fn(*args))
            except BaseException as exc:  # noqa: BLE001 - handed to the future's owner
                fut.set_exception(exc)

    def shutdown(self, cancel: list[Future[Any]]) -> None:
        """No more calls; ``cancel`` those not started (the running one is left to end or
        to die with the process)."""
        for fut in cancel:
            fut.cancel()
        self._jobs.put(None)


class Host(Protocol):
    """What the desk needs of the service."""

    loop: asyncio.AbstractEventLoop | None
    stop_signalled: bool
    subscribers: list[Callable[[str, list[Any], list[EventRow]], None]]

    def event(self, st: MachineState, ev: EventRow) -> None: ...

    def report(self, machine: str, kind: str, detail: str, count: int = 1) -> None: ...


class SliverDesk:
    """The sliver watch and the leveller's recommendation of every machine of ``service``."""

    def __init__(self, service: Host, window_m: float = WINDOW_M,
                 search_mm: float = SEARCH_MM) -> None:  # fmt: skip
        self.service = service
        self.window_m, self.search_mm = window_m, search_mm
        self._watch_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sliver")
        self._level_pool = DaemonWorker("leveller")
        self._pending: set[Future[Any]] = set()
        self._described: dict[str, str] = {}  # each machine's description, as last taken
        self.lines_learned: Callable[[MachineState], None] = lambda st: None
        """Called when a check completed a learning machine's own lines (the service hands
        them to its baseline: :meth:`~drafttwin.twin.faults.FaultDesk.sliver_lines`)."""

    # ---- readings in ----------------------------------------------------------------------
    def batch(self, st: MachineState, b: SliverBatch) -> None:
        """A batch of readings: a repeated or older one (QoS 1 may send one twice) is
        counted and dropped; the others feed the sliver watch and the leveller's window."""
        if b.seq <= st.sliver_seq:
            st.sliver_repeated += 1
            return
        st.sliver_seq = b.seq
        if st.sliver is None:
            st.sliver = SliverWatch(st.twin.train, StapleDiagram.preset("cotton")
                                    if st.level is None else st.level.context.staple,
                                    sensor_length_m=SLIVER_SENSOR_M, checks_now=False,
                                    fibre_scale=1.0 if st.level is None
                                    else st.level.context.fibre_scale,
                                    reference=None if st.baseline is None
                                    else st.baseline.sliver_reference,
                                    nominal_ktex=None if st.level is None
                                    else st.level.context.nominal_ktex)  # fmt: skip
        # while the machine learns its healthy state, its sliver's lines are learned too
        st.sliver.learning = st.watch is not None and st.watch.learning
        st.sliver.push(b.delivered_m, b.ktex, b.time_s)
        for e in st.sliver.take_count_excursions():
            self._event(st, "sliver-count" if e.out else "sliver-count-back", e.text(), e.time_s)
        if st.sliver.due() and not st.sliver_busy:
            st.sliver_busy = True
            fut = self._watch_pool.submit(st.sliver.check)
            fut.add_done_callback(lambda f: self._soon(self._alarms, st, f))
        if st.level is not None:
            st.level.push(b.delivered_m, b.ktex, b.time_s, b.infeed_ktex, b.fed_length_m)
            self._level(st)

    def describe(self, st: MachineState, text: str) -> None:
        """The machine's description of its sliver (the leveller's setting, the fibres, the
        sensors), checked before it is trusted; a new one starts the leveller's window."""
        section = parse_description(text)
        if isinstance(section, str):
            self.service.report(st.twin.name, "dropped", section)
            return
        key = json.dumps(section, sort_keys=True)
        if st.level is not None and self._described.get(st.twin.name) == key:
            return  # said again (a reconnect, a retained message): the window goes on
        try:
            context = LevelContext.of(section)
        except (DrafttwinError, KeyError, TypeError, ValueError) as exc:  # never trusted
            self.service.report(st.twin.name, "dropped", f"description refused: {exc}"[:200])
            return
        self._described[st.twin.name] = key
        st.level = LevelWatch(context, self.window_m, self.search_mm)
        if st.sliver is not None:  # described after its first readings
            st.sliver.hold_count(context.nominal_ktex)
        s = context.setting
        what = ("no leveller" if s is None else
                f"intensity {s.intensity:g}, action point {s.action_point_mm:.1f} mm")  # fmt: skip
        every = (f"a recommendation every {self.window_m:g} m of sliver" if s is not None
                 else "no setting to recommend from (sliver level --action-point MM "
                 "--intensity 0 on its record places a first one)")  # fmt: skip
        self._event(st, "leveller", f"the machine's leveller: {what}; fibres "
                    f"{context.staple.name} ({context.fibres}); {every}")  # fmt: skip

    # ---- the workers ----------------------------------------------------------------------
    def _soon(self, fn: Any, *args: Any) -> None:
        loop = self.service.loop
        if loop is not None and loop.is_running():
            with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
                loop.call_soon_threadsafe(fn, *args)
                return
        fn(*args)

    def _alarms(self, st: MachineState, fut: Future[list[SliverAlarm]]) -> None:
        st.sliver_busy = False
        if not fut.cancelled() and (exc := fut.exception()) is not None:
            self._event(st, "sliver-error", f"a sliver window was not judged "
                        f"({type(exc).__name__}: {exc})"[:300])  # fmt: skip
        alarms = [] if fut.cancelled() or fut.exception() is not None else fut.result()
        if st.baseline is not None and st.baseline.sliver_reference is None:
            self.lines_learned(st)
        for a in alarms:
            assert st.sliver is not None
            self._event(st, "sliver-chimney", st.sliver.text(a), a.time_s)

    def _level(self, st: MachineState) -> None:
        """Hand a complete window to the leveller's worker (one at a time per twin)."""
        level = st.level
        if level is None or st.level_busy or not level.due():
            return
        record = level.take()
        st.level_busy = True
        t0 = time.monotonic()
        fut = self._level_pool.submit(level.check, record)
        self._pending.add(fut)
        fut.add_done_callback(lambda f: self._soon(self._levelled, st, level, record, f, t0))

    def _levelled(self, st: MachineState, level: LevelWatch, record: Any, fut: Future[Any],
                  t0: float) -> None:  # fmt: skip
        self._pending.discard(fut)
        st.level_busy = False
        level.took_s = time.monotonic() - t0
        if fut.cancelled():
            return
        if fut.exception() is not None:
            level.failed = f"{type(fut.exception()).__name__}: {fut.exception()}"[:200]
        else:
            level.accept(record, fut.result())
        if level is st.level:
            self._event(st, "leveller-advice", level.text(), float(record.time_s[-1]))
            self._level(st)  # the next window may be complete already

    def _event(self, st: MachineState, kind: str, text: str, time_s: float | None = None) -> None:
        ts = int(round((time.time() if time_s is None else time_s) * 1e6))
        ev = EventRow(st.twin.name, kind, ts, text)
        self.service.event(st, ev)
        for push in self.service.subscribers:
            push(st.twin.name, [], [ev])

    # ---- the end ---------------------------------------------------------------------------
    async def settle(self) -> None:
        """Let the windows in progress finish, unless a stop signal came before or comes
        meanwhile (then abandoned: their worker does not hold the process), then close the
        workers."""
        while self._pending and not self.service.stop_signalled:
            await asyncio.wait([asyncio.wrap_future(f) for f in list(self._pending)],
                               timeout=SIGNAL_POLL_S)  # fmt: skip
            await asyncio.sleep(0)  # their results, handed to the loop
        self._watch_pool.shutdown(wait=True, cancel_futures=True)
        await asyncio.sleep(0)
        self._level_pool.shutdown(list(self._pending))

    # ---- figures ---------------------------------------------------------------------------
    @staticmethod
    def status(st: MachineState) -> dict[str, Any]:
        """The machine's sliver and leveller, as /api/status shows them."""
        sliver = None if st.sliver is None else st.sliver.summary()
        if sliver is not None:
            sliver["repeated_batches"] = st.sliver_repeated
            last = st.sliver.last  # type: ignore[union-attr]
            g = None if last is None else last.spectrogram
            sliver["spectrogram"] = None if g is None else {
                "wavelength_m": g.wavelength_m.tolist(), "amplitude_pct": g.amplitude_pct.tolist(),
                "ideal_pct": None if g.ideal_pct is None else g.ideal_pct.tolist(),
                "chimney": g.chimney.tolist(), "length_m": g.length_m,
                "own": _own_channels(g.wavelength_m, last.known if last else [])}  # fmt: skip
        return {"sliver": sliver, "leveller": None if st.level is None else st.level.summary()}


def _own_channels(wavelength_m: Any, known: list[Any]) -> list[bool]:
    """Channels holding one of the machine's own lines (drawn apart from new chimneys)."""
    centres = [float(c.extra.get("channel_m", c.wavelength_m)) for c in known]
    return [any(abs(math.log(float(w) / c)) < SAME_CHANNEL for c in centres)
            for w in wavelength_m]  # fmt: skip


__all__ = ["SLIVER_SENSOR_M", "SliverDesk"]
