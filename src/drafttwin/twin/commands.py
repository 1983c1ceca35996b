"""An operator's commands on a twin's machine (relearn its healthy state, acknowledge or confirm
its alarms), one implementation for the twin's REST API and a hall's shard: each runs on the
twin's loop and returns its answer, or raises :class:`Refused` with the HTTP status to answer."""

from __future__ import annotations

from typing import Any

from drafttwin._json import to_strict
from drafttwin.twin.service import TwinService, detector_state


class Refused(Exception):
    """A command the twin cannot carry out: ``status`` (404, 409) and why."""

    def __init__(self, status: int, text: str) -> None:
        super().__init__(text)
        self.status = status
        self.text = text


def _state(service: TwinService, machine: str) -> Any:
    st = service.states.get(machine)
    if st is None:
        raise Refused(404, f"no machine {machine[:100]!r}")
    return st


def relearn(service: TwinService, machine: str, why: str) -> dict[str, Any]:
    """Forget the machine's learned healthy state and learn it again; its detector after."""
    st = _state(service, machine)
    if not service.relearn(machine, why):
        raise Refused(409, f"machine {machine!r} has no fault detector")
    return to_strict({"machine": machine, "detector": detector_state(st)})  # type: ignore[no-any-return]


def take_alarms(service: TwinService, machine: str, what: str, comment: str = "",
                alarm: str | None = None) -> dict[str, Any]:  # fmt: skip
    """``what`` = acknowledge or confirm the machine's retained alarms (or the one whose id is
    ``alarm``); how many it took and the alarms after."""
    if what not in ("acknowledge", "confirm"):
        raise Refused(404, "acknowledge or confirm")
    _state(service, machine)
    if alarm is not None and alarm not in {a.id for a in service.book.retained(machine)}:
        raise Refused(404, f"machine {machine!r} has no retained alarm {alarm!r}")
    n = service.faults.acknowledge(machine, comment[:500], what == "confirm", alarm)
    return to_strict({"machine": machine, "taken": n,  # type: ignore[no-any-return]
                      "alarms": [a.to_dict() for a in service.book.retained(machine)]})  # fmt: skip


__all__ = ["Refused", "relearn", "take_alarms"]
