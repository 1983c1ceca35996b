"""The twin's fault desk: each machine's diagnosis fed, its alarms booked, its windows
ranked in the worker, what it learnt kept with its identity (docs/twin.md, "Faults live").

:class:`FaultDesk` is the part of the service that deals with faults; the service (its
*host*) owns the machines, the store and the subscribers, and calls it for every processed
row and at the end of a run.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

from drafttwin.diagnosis.cusum import Alarm
from drafttwin.diagnosis.detect import FaultDetector
from drafttwin.diagnosis.stream import POST_S, RankRequest, Step
from drafttwin.sliver.reference import KNOWN_FACTOR
from drafttwin.twin.alarms import AlarmBook, stored_alarm
from drafttwin.twin.faultwatch import Locator, alarm_detail, stored_baseline
from drafttwin.twin.state import MachineState
from drafttwin.twin.store.baselines import Baseline, BaselineStore
from drafttwin.twin.store.db import EventRow, SampleRow
from drafttwin.wire.identity import MachineIdentity

LOCATE_WAIT_S = 2.0
"""After a stop signal, how long the rankings still running may take to finish (stored; one
takes about a second in the warm worker). One that does not finish is kept in the store and
ranked when the twin starts again there (without a store: stored as not localised)."""
LOCATE_END_S = 60.0
"""At the end of a run that was not stopped (a replay ended, --duration): how long the
rankings may take (a worker still starting included)."""


class Host(Protocol):
    """What the desk needs of the service."""

    states: dict[str, MachineState]
    subscribers: list[Callable[[str, list[SampleRow], list[EventRow]], None]]
    metrics: Any
    loop: asyncio.AbstractEventLoop | None
    stop_signalled: bool

    def event(self, st: MachineState, ev: EventRow) -> None: ...


class FaultDesk:
    """Faults of every machine of one service (see the module docstring)."""

    def __init__(self, host: Host) -> None:
        self.host = host
        self.locator = Locator()
        self.book = AlarmBook()  # every alarm, active or retained for an operator
        self.baselines: BaselineStore | None = None  # where machines' baselines are kept
        self._ranking: dict[int, tuple[MachineState, RankRequest, FaultDetector]] = {}

    def watch_rows(self, st: MachineState, rows: list[SampleRow]) -> list[EventRow]:
        """Feed the machine's diagnosis; alarms become events at once, windows are ranked in
        the worker, a learning state that ends stores the machine's baseline."""
        assert st.watch is not None
        out = []
        for row in rows:
            out += self.took(st, st.watch.add(row), row.ts_us)
        return out

    def took(self, st: MachineState, step: Step, ts_us: int,
              judge: FaultDetector | None = None) -> list[EventRow]:  # fmt: skip
        """What a machine's diagnosis brought: its learning's end, alarms, windows to rank
        (with ``judge``, the detector that raised them, or the machine's present one)."""
        out = []
        if step.learned is not None:
            out.append(self.learned(st, step.learned, ts_us))
        out += self.fault_events(st, step)
        for a in step.cleared:
            out.append(self.cleared(st, a, "its stream is back at its healthy baseline"))
        for req in step.requests:
            self.locate(st, req, judge)
        return out

    def cleared(self, st: MachineState, alarm: Alarm, why: str,
                 when_s: float | None = None) -> EventRow:  # fmt: skip
        """An alarm returned to normal (its OPC UA condition inactive, retained until
        acknowledged and confirmed)."""
        from drafttwin._json import dumps_strict

        at = st.twin.last_us / 1e6 if when_s is None else when_s
        self.book.cleared(st.twin.name, alarm, at, why)
        ev = EventRow(st.twin.name, "fault-cleared", int(round(at * 1e6)),
                      dumps_strict({"test": alarm.test, "rule": alarm.rule,
                                    "alarm_s": alarm.time_s, "cleared_s": at, "why": why},
                                   indent=None))  # fmt: skip
        self.host.event(st, ev)
        return ev

    def fault_events(self, st: MachineState, step: Step) -> list[EventRow]:
        """The alarms a step raised: booked, stored, their events (pushed by the caller)."""
        out = []
        for a in step.alarms:
            st.faults += 1
            self.book.raised(st.twin.name, a, "fault" if a.direction else "sensor-fault")
            note = f"probable cause after {POST_S if st.watch is None else st.watch.post_s:g} s"
            if a.direction == 0 and st.watch is not None:  # a sensor rule: its channel is the
                # cause, sized later
                ev = EventRow(st.twin.name, "sensor-fault", int(round(a.time_s * 1e6)),
                              alarm_detail(a, [st.watch.sensor_cause(a, step)], note))  # fmt: skip
            else:
                ev = EventRow(st.twin.name, "fault", int(round(a.time_s * 1e6)),
                              alarm_detail(a, note=note,
                                           baseline=step.baselines.get((a.time_s, a.test))))  # fmt: skip
            self.host.event(st, ev)
            out.append(ev)
        return out

    def learned(self, st: MachineState, detector: FaultDetector, ts_us: int) -> EventRow:
        """A machine finished learning: its baseline, stored with its identity."""
        assert st.watch is not None
        start = st.watch.learn_from_s if st.watch.learn_from_s is not None else ts_us / 1e6
        st.baseline = Baseline(st.twin.name, detector, st.model_sha256, st.identity,
                               st.watch.learn_s, start, ts_us / 1e6, st.prior)  # fmt: skip
        where = self._store(st.baseline, forget_learning=True)
        who = f" ({st.identity})" if st.identity is not None else ""
        ev = EventRow(st.twin.name, "learned", ts_us,
                      f"learned its healthy state{who} over {st.watch.learn_s:g} s of running"
                      + ("" if st.prior is None else f" on top of {st.prior['file']}") + where
                      + ("" if detector.lags_watched else "; angle lags not watched"))  # fmt: skip
        self.host.event(st, ev)
        if st.sliver is not None:  # its sliver's lines: kept once their windows are checked
            st.sliver.end_learning()
            self.sliver_lines(st)
        return ev

    def _store(self, baseline: Baseline, forget_learning: bool = False) -> str:
        """Write ``baseline`` to the store (the learning state it came from forgotten):
        "; stored in PATH", or why not, for the event that says so."""
        if self.baselines is None:
            return ""
        try:
            where = f"; stored in {self.baselines.save(baseline)}"
            if forget_learning:
                self.baselines.forget_learning(baseline.machine)
        except OSError as exc:
            return f"; not stored ({type(exc).__name__}: {exc})"
        return where

    def sliver_lines(self, st: MachineState) -> None:
        """The lines the machine's sliver showed while it learned, complete: kept in its
        baseline (a restarted twin judges by them at once) and said."""
        lines = None if st.sliver is None or not st.sliver.learned_final else st.sliver.learned
        if lines is None or st.baseline is None or st.baseline.sliver_reference is not None:
            return
        st.baseline.sliver_reference = lines
        where = self._store(st.baseline)
        ev = EventRow(st.twin.name, "learned", int(time.time() * 1e6),
                      f"learned its sliver's own lines over {lines.metres:.0f} m "
                      f"({lines.windows} window(s)): a chimney up to {KNOWN_FACTOR:g} x them "
                      f"is the machine's, not alarmed{where}")  # fmt: skip
        self.host.event(st, ev)
        for push in self.host.subscribers:
            push(st.twin.name, [], [ev])

    def announce(self, st: MachineState) -> None:
        """At the start: what the machine's detector does (learns, or watches with the
        baseline the store kept), and a stored baseline refused, by name."""
        w = st.watch
        assert w is not None
        now = int(time.time() * 1e6)
        if st.refused is not None:
            self.host.event(st, EventRow(st.twin.name, "baseline-refused", now,
                                     f"stored baseline not used: {st.refused}"))  # fmt: skip
        if w.learning:
            prior = "" if st.prior is None else f", on top of {st.prior['file']}"
            done = w.learner.learned_s if w.learner is not None else 0.0
            kept = f" ({done:g} s of it learned before the twin restarted)" if done else ""
            text = (f"learning its healthy state: {w.learn_s:g} s of running{prior}{kept}; no "
                    "fault alarm meanwhile")  # fmt: skip
            self.host.event(st, EventRow(st.twin.name, "learning", now, text))
        elif st.baseline is not None:
            b = st.baseline
            who = "" if b.identity is None else f" on {b.identity}"
            self.host.event(st, EventRow(st.twin.name, "baseline", now,
                                     f"watching with the baseline learned{who} over "
                                     f"{b.learned_s:g} s of running"))  # fmt: skip
        else:
            self.judged_as_is(st)

    def acknowledge(self, machine: str, comment: str = "", confirm: bool = False,
                    alarm_id: str | None = None) -> int:  # fmt: skip
        """An operator acknowledges (or confirms: those acknowledged) the machine's retained
        alarms, or the one ``alarm_id``: stored as an event ``alarm-ack``; the number taken."""
        st = self.host.states.get(machine)
        if st is None:
            return 0
        # an alarm already in the asked state is not taken again: a repeated or empty request
        # changes nothing and stores nothing (a client in a loop had flooded store and console)
        chosen = [a for a in self.book.retained(machine)
                  if (alarm_id is None or a.id == alarm_id) and (a.acked or not confirm)
                  and not (a.confirmed if confirm else a.acked)]  # fmt: skip
        taken = [a for a in chosen if self.book.acknowledge(a.id, comment, confirm) is not None]
        if not taken:
            return 0
        what = "confirmed" if confirm else "acknowledged"
        ev = EventRow(machine, "alarm-ack", int(time.time() * 1e6),
                      json.dumps({"what": what, "alarms": [a.id for a in taken],
                                  "comment": comment[:500]}))  # fmt: skip
        self.host.event(st, ev)
        for push in self.host.subscribers:
            push(machine, [], [ev])
        return len(taken)

    def judged_as_is(self, st: MachineState) -> None:
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
        self.host.event(st, EventRow(st.twin.name, kind, int(time.time() * 1e6), text))

    def relearn(self, machine: str, why: str = "operator's command") -> bool:
        """Forget a machine's baseline and learn again (after maintenance); False: no such
        machine with a detector."""
        st = self.host.states.get(machine)
        if st is None or st.watch is None:
            return False
        judge = st.watch.detector  # the windows of the old run were raised by it
        self.took(st, st.watch.relearn(), int(time.time() * 1e6), judge)
        for booked in self.book.clear_machine(machine, f"serviced: {why}"):
            self.host.event(st, EventRow(machine, "fault-cleared", int(time.time() * 1e6),
                                     json.dumps({"test": booked.test, "alarm_s": booked.time_s,
                                                 "why": booked.cleared_why})))  # fmt: skip
        st.baseline = None
        if st.sliver is not None:
            st.sliver.relearn()
        if self.baselines is not None:
            self.baselines.forget(machine)
        ev = EventRow(machine, "learning", int(time.time() * 1e6),
                      f"learning its healthy state again ({why}): {st.watch.learn_s:g} s of "
                      "running, no fault alarm meanwhile")  # fmt: skip
        self.host.event(st, ev)
        for push in self.host.subscribers:
            push(machine, [], [ev])
        return True

    def identify(self, machine: str, identity: MachineIdentity) -> None:
        """The source says who the machine is: a baseline learned on another machine is
        refused by name, and the machine learns its own."""
        st = self.host.states.get(machine)
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
            self.judged_as_is(st)

    def locate(self, st: MachineState, req: RankRequest, judge: FaultDetector | None = None,
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
            if self.host.loop is not None and self.host.loop.is_running():
                self.host.loop.call_soon_threadsafe(self.cause, st, ev, causes, r.alarm)
            else:
                self.cause(st, ev, causes, r.alarm)

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

    def cause(self, st: MachineState, ev: EventRow, causes: list[dict[str, Any]] | None,
               alarm: Alarm | None = None) -> None:  # fmt: skip
        if alarm is not None:
            self.book.caused(st.twin.name, alarm, causes)
        self.host.event(st, ev)
        if self.host.metrics is not None and hasattr(self.host.metrics, "cause"):
            top = causes[0] if causes else None
            self.host.metrics.cause(ev.machine, "none" if top is None else
                               f"{top['element']}:{top['kind']}")  # fmt: skip
        for push in self.host.subscribers:
            push(st.twin.name, [], [ev])

    async def settle(self) -> None:
        """At the end: rank what each open window has, wait for the rankings running
        (:data:`LOCATE_WAIT_S` after a stop signal, else :data:`LOCATE_END_S`); one not done
        then is kept for the next twin, or stored as not localised."""
        for st in self.host.states.values():
            if st.watch is not None:
                last = st.twin.last_us if st.twin.last_us else int(time.time() * 1e6)
                self.took(st, st.watch.flush(), last)
        start = time.monotonic()
        while self._ranking:
            budget = LOCATE_WAIT_S if self.host.stop_signalled else LOCATE_END_S
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
            self.cause(st, EventRow(st.twin.name, "fault-cause", int(round(req.alarm.time_s * 1e6)),
                                     alarm_detail(req.alarm, None, why)), None)  # fmt: skip
        self.keep_learning()
        self.locator.close()

    def keep_learning(self) -> None:
        """Each learning machine's blocks so far, kept for the next twin on this store."""
        if self.baselines is None:
            return
        for st in self.host.states.values():
            w = st.watch
            if w is not None and w.learner is not None and w.learner.blocks:
                with contextlib.suppress(OSError):
                    self.baselines.save_learning(st.twin.name, w.learner, st.identity,
                                                 st.model_sha256, w.learn_from_s)  # fmt: skip

    def restore(self, events: list[EventRow]) -> None:
        """The alarm book as the stored run left it (:meth:`AlarmBook.restore`); each
        machine's newest retained alarm is its last fault again (status, hall page)."""
        for ev in self.book.restore(events):
            st = self.host.states.get(ev.machine)
            if st is not None:
                st.last_fault = ev
        for ev in events:  # the active ones are watched for their return to normal again
            st = self.host.states.get(ev.machine)
            if ev.kind not in ("fault", "sensor-fault") or st is None or st.watch is None:
                continue
            alarm = stored_alarm(ev.detail)
            booked = None if alarm is None else self.book.alarms.get(
                self.book.key(ev.machine, alarm.time_s, alarm.test))  # fmt: skip
            if alarm is not None and booked is not None and booked.active:
                st.watch.keep_watching(alarm, stored_baseline(ev.detail))

    def resume_pending(self) -> None:
        """Rank the windows a stopped twin left (their alarms are stored already)."""
        if self.baselines is None:
            return
        for st in self.host.states.values():
            if st.watch is None:
                continue
            for path, req, det, post_s in self.baselines.pending(st.twin.name):
                self.locate(st, req, det, post_s, kept=path)


__all__ = ["LOCATE_END_S", "LOCATE_WAIT_S", "FaultDesk", "Host"]
