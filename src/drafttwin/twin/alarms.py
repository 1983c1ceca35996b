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

import time
from dataclasses import asdict, dataclass
from typing import Any

from drafttwin.diagnosis.detect import Alarm

SEVERITY = {"fault": 700, "sensor-fault": 500, "sliver-chimney": 400}
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

    def _trim(self, machine: str) -> None:
        done = [a for a in self.alarms.values() if a.machine == machine and not a.retained]
        for a in sorted(done, key=lambda a: a.time_s)[:-KEPT] if len(done) > KEPT else []:
            del self.alarms[a.id]


__all__ = ["SEVERITY", "AlarmBook", "BookedAlarm"]
