"""OPC UA Alarms & Conditions (Part 9) on the twin's server, written on top of asyncua, which
emits condition events but implements none of the condition methods.

One condition per machine (``ns=2;s=NAME.Alarm``, type AlarmConditionType, events emitted by
the Server object with the machine as SourceNode): it stands for the machine's retained
alarms in the twin's alarm book (:mod:`drafttwin.twin.alarms`), the most severe first in its
Message. ActiveState is true while any is active (until it returns to normal or the machine
is serviced and learnt again), AckedState and ConfirmedState while all are; Retain while any
is active or not yet acknowledged and confirmed; Severity the highest.

* **ConditionRefresh** (``i=3875``, and ConditionRefresh2 ``i=12912``): a client that
  connects (or reconnects) after an alarm calls it; the server answers its subscription with
  RefreshStartEvent, every retained condition's current state, RefreshEndEvent.
* **Acknowledge** (``i=9111``) and **Confirm** (``i=9113``) with the EventId of the
  condition's last event and a comment: the machine's retained alarms are acknowledged
  (confirmed), the twin stores it (event ``alarm-ack``) and emits the condition's new state.
  An EventId that is not the condition's last gives BadEventIdUnknown, as Part 9 says.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from drafttwin.twin.alarms import BookedAlarm

REFRESH, REFRESH2, ACKNOWLEDGE, CONFIRM = 3875, 12912, 9111, 9113


def _ua() -> Any:
    from asyncua import ua

    return ua


class Conditions:
    """The machines' conditions on one asyncua server.

    Args:
        retained: the machine's retained alarms, most severe first (the service's book).
        acknowledge: acknowledge (``confirm=False``) or confirm the machine's retained alarms
            with a comment (stored by the service as an ``alarm-ack`` event).
    """

    def __init__(self, retained: Callable[[str], list[BookedAlarm]],
                 acknowledge: Callable[[str, str, bool], Any]) -> None:  # fmt: skip
        self.retained, self.acknowledge = retained, acknowledge
        self.generators: dict[str, Any] = {}  # machine -> its AlarmConditionType generator
        self.by_condition: dict[str, str] = {}  # condition NodeId text -> machine
        self.last_event: dict[str, bytes] = {}  # machine -> EventId of its last event
        self.server: Any = None

    async def install(self, server: Any) -> None:
        """Link the condition methods of the standard address space to this object."""
        ua = _ua()

        self.server = server
        for method, call in ((REFRESH, self._refresh), (REFRESH2, self._refresh2),
                             (ACKNOWLEDGE, self._acknowledge), (CONFIRM, self._confirm)):  # fmt: skip
            server.link_method(server.get_node(ua.NodeId(method)), call)

    def add(self, machine: str, generator: Any, condition: Any) -> None:
        """A machine's condition: its event generator and the condition's NodeId."""
        self.generators[machine] = generator
        self.by_condition[condition.to_string()] = machine

    async def emit(self, machine: str, subscription_id: int | None = None,
                   when: Any = None) -> None:  # fmt: skip
        """The machine's condition in its present state (to every client, or one
        subscription during a refresh); ``when``: the time of the change (default: the most
        severe alarm's sample time)."""
        ua = _ua()

        gen = self.generators[machine]
        alarms = self.retained(machine)
        e = gen.event
        top = alarms[0] if alarms else None
        active = any(a.active for a in alarms)
        acked = all(a.acked for a in alarms)
        confirmed = all(a.confirmed for a in alarms)
        e.ConditionName = "fault" if top is None else top.kind
        e.Severity = 1 if top is None else max(a.severity for a in alarms)
        e.Retain = bool(alarms)
        states = (("EnabledState", True, "Enabled", "Disabled"),
                  ("ActiveState", active, "Active", "Inactive"),
                  ("AckedState", acked, "Acknowledged", "Unacknowledged"),
                  ("ConfirmedState", confirmed, "Confirmed", "Unconfirmed"))  # fmt: skip
        for prop, value, yes, no in states:
            setattr(e, f"{prop}/Id", value)
            setattr(e, prop, ua.LocalizedText(yes if value else no))
        if when is None and top is not None:
            from drafttwin.twin.publish.payload import utc

            when = utc(int(round(top.time_s * 1e6)))
        await gen.trigger(time_attr=when, message=self._message(machine, alarms),
                          subscription_id=subscription_id)  # fmt: skip
        self.last_event[machine] = bytes(e.EventId.Value)

    @staticmethod
    def _message(machine: str, alarms: list[BookedAlarm]) -> str:
        if not alarms:
            return f"{machine}: no alarm"
        parts = []
        for a in alarms:
            cause = (
                ""
                if a.cause is None
                else f", probable cause {a.cause['element']}:{a.cause['kind']}"
            )
            state = "active" if a.active else "returned to normal"
            parts.append(f"{a.kind} {a.test} ({state}{cause})")
        return f"{machine}: " + "; ".join(parts)

    # ---- the methods ------------------------------------------------------------------------
    async def _refresh(self, parent: Any, subscription_id: Any) -> list[Any]:
        await self._refresh_for(_value(subscription_id))
        return []

    async def _refresh2(self, parent: Any, subscription_id: Any, item_id: Any) -> list[Any]:
        await self._refresh_for(_value(subscription_id))
        return []

    async def _refresh_for(self, subscription_id: int) -> None:
        ua = _ua()

        server = self.server
        start = await server.get_event_generator(ua.ObjectIds.RefreshStartEventType,
                                                 server.nodes.server)  # fmt: skip
        end = await server.get_event_generator(ua.ObjectIds.RefreshEndEventType,
                                               server.nodes.server)  # fmt: skip
        await start.trigger(message="ConditionRefresh", subscription_id=subscription_id)
        for machine in self.generators:
            if self.retained(machine):
                await self.emit(machine, subscription_id)
        await end.trigger(message="ConditionRefresh", subscription_id=subscription_id)

    async def _acknowledge(self, parent: Any, event_id: Any, comment: Any) -> Any:
        return await self._ack(parent, event_id, comment, confirm=False)

    async def _confirm(self, parent: Any, event_id: Any, comment: Any) -> Any:
        return await self._ack(parent, event_id, comment, confirm=True)

    async def _ack(self, parent: Any, event_id: Any, comment: Any, *, confirm: bool) -> Any:
        ua = _ua()

        machine = self.by_condition.get(parent.to_string())
        if machine is None:
            return ua.StatusCode(ua.StatusCodes.BadNodeIdUnknown)
        if bytes(_value(event_id) or b"") != self.last_event.get(machine):
            return ua.StatusCode(ua.StatusCodes.BadEventIdUnknown)
        text = _value(comment)
        self.acknowledge(machine, str(getattr(text, "Text", text) or ""), confirm)
        import datetime as dt

        await self.emit(machine, when=dt.datetime.now(dt.UTC))
        return ua.StatusCode(ua.StatusCodes.Good)


def _value(v: Any) -> Any:
    """A method argument's value (asyncua passes Variants)."""
    return getattr(v, "Value", v)


__all__ = ["Conditions"]
