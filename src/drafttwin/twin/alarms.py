"""The twin's alarm book: every alarm raised, its cause, whether it is still active, and
whether an operator acknowledged and confirmed it (the states of OPC UA Part 9's
AcknowledgeableConditionType and AlarmConditionType, which the twin's OPC UA server shows and
its MQTT publisher retains per machine).

An alarm is *active* from its raising until it returns to normal
(:mod:`drafttwin.diagnosis.clearance`) or the machine is serviced and learnt again; it is
*retained* (shown to every client, whenever it connects) while it is active or not yet both
acknowledged and confirmed.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import time
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from typing import Any

from drafttwin.diagnosis.cusum import Alarm

SEVERITY = {"fault": 700, "sliver-count": 600, "sensor-fault": 500, "sliver-chimney": 400}
"""OPC UA severity (1-1000) of each alarm kind: a machine fault first."""
KEPT = 200
"""Alarms kept per machine once they are no longer retained (for the page's list)."""


@dataclass
class BookedAlarm:
    """One alarm in the book."""

    id: str
    machine: str
    kind: str  # fault, sensor-fault
    test: str
    rule: str
    time_s: float  # the alarm block's end (source time)
    severity: int
    direction: int = 0  # +1 the stream went up, -1 down, 0 for the sensor rules
    change_s: float | None = None  # the estimated onset (source time)
    cause: dict[str, Any] | None = None  # the first ranked cause
    active: bool = True
    acked: bool = False
    confirmed: bool = False
    cleared_s: float | None = None  # when it returned to normal (source time)
    cleared_why: str = ""
    comment: str = ""

    @property
    def retained(self) -> bool:
        return self.active or not (self.acked and self.confirmed)

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "retained": self.retained}


class AlarmBook:
    """All machines' alarms, most severe and newest first where listed."""

    def __init__(self) -> None:
        self.alarms: dict[str, BookedAlarm] = {}
        self.changed = 0  # bumped on every change (publishers send the retained state then)

    @staticmethod
    def key(machine: str, time_s: float, test: str) -> str:
        return f"{machine}:{int(round(time_s * 1e6))}:{test}"

    def raised(self, machine: str, alarm: Alarm, kind: str) -> BookedAlarm:
        a = BookedAlarm(self.key(machine, alarm.time_s, alarm.test), machine, kind, alarm.test,
                        alarm.rule, alarm.time_s, SEVERITY.get(kind, 500), alarm.direction,
                        alarm.change_s)  # fmt: skip
        self.alarms[a.id] = a
        self._trim(machine)
        self.changed += 1
        return a

    def caused(self, machine: str, alarm: Alarm, causes: list[dict[str, Any]] | None) -> None:
        a = self.alarms.get(self.key(machine, alarm.time_s, alarm.test))
        if a is not None and causes:
            a.cause = causes[0]
            self.changed += 1

    def cleared(self, machine: str, alarm: Alarm, when_s: float, why: str) -> BookedAlarm | None:
        a = self.alarms.get(self.key(machine, alarm.time_s, alarm.test))
        if a is None or not a.active:
            return None
        a.active, a.cleared_s, a.cleared_why = False, when_s, why
        self.changed += 1
        return a

    def clear_machine(self, machine: str, why: str) -> list[BookedAlarm]:
        """Every active alarm of a machine returned to normal (it was serviced)."""
        out = []
        for a in self.alarms.values():
            if a.machine == machine and a.active:
                a.active, a.cleared_s, a.cleared_why = False, time.time(), why
                out.append(a)
        self.changed += bool(out)
        return out

    def acknowledge(
        self, alarm_id: str, comment: str = "", confirm: bool = False
    ) -> BookedAlarm | None:
        """An operator's acknowledgement (``confirm``: confirmation); None: no such alarm."""
        a = self.alarms.get(alarm_id)
        if a is None:
            return None
        if confirm:
            a.confirmed = True
        else:
            a.acked = True
        a.comment = comment[:500] or a.comment
        self.changed += 1
        return a

    def retained(self, machine: str | None = None) -> list[BookedAlarm]:
        """The alarms every client is shown: most severe first, then the newest."""
        out = [a for a in self.alarms.values()
               if a.retained and (machine is None or a.machine == machine)]  # fmt: skip
        return sorted(out, key=lambda a: (-a.severity, -a.time_s))

    def restore(self, events: Iterable[Any]) -> list[Any]:
        """The book as a stored run left it, from its events (``machine``, ``kind``,
        ``ts_us``, ``detail`` each, any order): alarms raised, their causes, returns to
        normal, acknowledgements and confirmations, applied in that order (an alarm carries
        the data's time, an acknowledgement the wall clock). Returns the alarm and cause
        events of the alarms still retained, oldest first: a restarted twin shows them as the
        run before it did (they had vanished from /api/alarms/active)."""
        by_kind: dict[str, list[Any]] = {}
        for ev in sorted(events, key=lambda e: e.ts_us):
            by_kind.setdefault(ev.kind, []).append(ev)
        for ev in by_kind.get("fault", []) + by_kind.get("sensor-fault", []):
            if (alarm := stored_alarm(ev.detail)) is not None:
                self.raised(ev.machine, alarm, ev.kind)
        for ev in by_kind.get("sensor-fault", []) + by_kind.get("fault-cause", []):
            if (alarm := stored_alarm(ev.detail)) is not None:
                self.caused(ev.machine, alarm, _loads(ev.detail).get("causes"))
        for ev in by_kind.get("fault-cleared", []):
            doc = _loads(ev.detail)
            with contextlib.suppress(KeyError, TypeError, ValueError):
                alarm = Alarm(float(doc["alarm_s"]), 0, str(doc["test"]), 0, float("nan"))
                self.cleared(ev.machine, alarm, float(doc.get("cleared_s", ev.ts_us / 1e6)),
                             str(doc.get("why", "")))  # fmt: skip
        for ev in by_kind.get("alarm-ack", []):
            doc = _loads(ev.detail)
            for alarm_id in doc.get("alarms", []) if isinstance(doc.get("alarms"), list) else []:
                self.acknowledge(str(alarm_id), str(doc.get("comment", "")),
                                 confirm=doc.get("what") == "confirmed")  # fmt: skip
        kept = {a.id for a in self.alarms.values() if a.retained}
        shown = [ev for kind in ("fault", "sensor-fault", "fault-cause")
                 for ev in by_kind.get(kind, [])
                 if (alarm := stored_alarm(ev.detail)) is not None
                 and self.key(ev.machine, alarm.time_s, alarm.test) in kept]  # fmt: skip
        return sorted(shown, key=lambda e: (e.ts_us, e.kind == "fault-cause"))

    def _trim(self, machine: str) -> None:
        done = [a for a in self.alarms.values() if a.machine == machine and not a.retained]
        for a in sorted(done, key=lambda a: a.time_s)[:-KEPT] if len(done) > KEPT else []:
            del self.alarms[a.id]


def _loads(detail: str) -> dict[str, Any]:
    try:
        doc = json.loads(detail)
    except (TypeError, ValueError):
        return {}
    return doc if isinstance(doc, dict) else {}


def stored_alarm(detail: str) -> Alarm | None:
    """The alarm an event's detail (:func:`~drafttwin.twin.faultwatch.alarm_detail`)
    describes, or ``None`` for a detail that does not."""
    doc = _loads(detail)
    try:
        onset = doc.get("onset_s")
        return Alarm(float(doc["alarm_s"]), 0, str(doc["test"]), int(doc.get("direction", 0)),
                     float("nan") if onset is None else float(onset),
                     str(doc.get("rule", "cusum")))  # fmt: skip
    except (KeyError, TypeError, ValueError):
        return None


CONSOLE_KINDS = ("fault", "fault-cause", "sensor-fault", "fault-cleared", "alarm-ack",
                 "sliver-chimney", "sliver-count", "sliver-count-back", "sliver-error", "learning", "learned", "baseline", "baseline-refused",
                 "detector-foreign", "identity", "leveller", "leveller-advice",
                 "source-reconnecting", "source-live", "gap", "no-samples", "silent")  # fmt: skip
"""Events a running twin prints on its console (its alarms and what its detector does)."""


def _clock(t_s: float | None) -> str:
    if t_s is None:
        return "?"
    if t_s > 1e8:  # epoch seconds: the plant's wall clock
        return _dt.datetime.fromtimestamp(t_s, _dt.UTC).strftime("%H:%M:%S UTC")
    return f"{t_s:.2f} s"


def cause_text(c: dict[str, Any] | None) -> str:
    """``main_belt belt_wear severity 0.50 [0.45, 0.55] (p 90 %)``."""
    if not c:
        return "probable cause pending"
    sev = c.get("severity")
    out = f"{c.get('element', '?')} {c.get('kind', '?')}"
    if isinstance(sev, float | int):
        out += f" severity {sev:.3g}"
        if isinstance(c.get("interval"), list) and len(c["interval"]) == 2:
            out += f" [{c['interval'][0]:.3g}, {c['interval'][1]:.3g}]"
    if isinstance(c.get("probability"), float | int):
        out += f" (p {100 * c['probability']:.0f} %)"
    return out


def event_line(machine: str, kind: str, ts_us: int, detail: str) -> str | None:
    """One console line for an event of :data:`CONSOLE_KINDS` (None for the others)."""
    if kind not in CONSOLE_KINDS:
        return None
    try:
        doc = json.loads(detail) if detail.startswith("{") else None
    except ValueError:
        doc = None
    if not isinstance(doc, dict):
        return f"{machine} {kind}: {detail}"
    at = _clock(ts_us / 1e6)
    if kind in ("fault", "sensor-fault", "fault-cause"):
        d = doc.get("direction", 0)
        way = " up" if d > 0 else " down" if d < 0 else ""
        what = f"{'sensor fault' if kind == 'sensor-fault' or d == 0 else 'fault'} {doc.get('test')}{way}"
        causes = doc.get("causes") or []
        if kind == "fault-cause":
            why = f"probable cause {cause_text(causes[0])}" if causes else doc.get("note", "")
            return f"{machine} {what} (alarm at {_clock(doc.get('alarm_s'))}): {why}"
        return f"ALARM {machine} {what} at {at}, onset {_clock(doc.get('onset_s'))}" + (
            f": {cause_text(causes[0])}" if causes else f"; {doc.get('note', '')}"
        )
    if kind == "fault-cleared":
        return f"{machine} alarm {doc.get('test')} (at {_clock(doc.get('alarm_s'))}) returned to normal at {at}: {doc.get('why', '')}"
    if kind == "alarm-ack":
        return (
            f"{machine}: {len(doc.get('alarms', []))} alarm(s) {doc.get('what', 'acknowledged')}"
            + (f" ({doc['comment']})" if doc.get("comment") else "")
        )
    return f"{machine} {kind}: {detail}"


__all__ = ["CONSOLE_KINDS", "SEVERITY", "AlarmBook", "BookedAlarm", "cause_text", "event_line"]
