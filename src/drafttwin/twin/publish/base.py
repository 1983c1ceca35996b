"""A publisher's outbox: what the twin's processing path hands over, bounded in rate and size.

The processing path only appends to a deque (no I/O, no await): a prediction per machine at
most ``max_hz`` times a second (wall clock), every alarm. A task of the publisher drains the
deque and talks to its clients; when they are slower than the twin, the oldest entries are
dropped and counted (``dropped``), so the twin keeps its pace and memory stays bounded. The
status of every machine goes out once a second from the same task, and at once when a
machine's state changes (ahead of the rows that came with the change).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections import deque
from typing import Any

from drafttwin.twin.publish.payload import ALARM_KINDS, Health, sliver
from drafttwin.twin.service import MachineState, TwinService
from drafttwin.twin.store.db import EventRow, SampleRow

QUEUE_LEN = 1000
"""Entries an outbox holds before the oldest are dropped."""
STATUS_S = 1.0
"""How often each machine's status (health and current alarm) is published, s."""
CLOSE_S = 2.0
"""How long closing a publisher may take (SIGTERM must end the twin within 5 s)."""


class Publisher:
    """Bounded outbox and its draining task; a protocol implements :meth:`open`,
    :meth:`send_prediction`, :meth:`send_alarm`, :meth:`send_status` and :meth:`close`."""

    kind = ""

    def __init__(self, spec: str, *, max_hz: float = 10.0, queue_len: int = QUEUE_LEN) -> None:
        self.spec = spec
        self.min_interval_s = 1.0 / max_hz
        self.queue_len = queue_len
        self.outbox: deque[tuple[str, Any]] = deque()
        self.dropped = 0  # outbox entries dropped (the oldest) because the clients were slow
        self.sent = 0
        self.failed = 0  # sends that raised (a client or broker gone); the twin runs on
        self.last_error = ""
        self._last_row: dict[str, float] = {}
        self._wake: asyncio.Event | None = None
        self.health: Health | None = None
        self.service: TwinService | None = None
        self._sliver_sent: dict[str, Any] = {}  # the sliver state last sent, per machine
        self._state_sent: dict[str, str] = {}  # the state last sent, per machine

    # ---- the twin's processing path: append only ------------------------------------------
    def on_rows(self, machine: str, rows: list[SampleRow], _events: list[EventRow]) -> None:
        if not rows:
            return
        now = time.monotonic()
        if now - self._last_row.get(machine, -math.inf) < self.min_interval_s:
            return
        self._last_row[machine] = now
        self._put(("prediction", rows[-1]))

    def on_event(self, ev: EventRow) -> None:
        if ev.kind in ALARM_KINDS:
            self._put(("alarm", ev))

    def _put(self, item: tuple[str, Any]) -> None:
        if len(self.outbox) >= self.queue_len:
            self.outbox.popleft()
            self.dropped += 1
        self.outbox.append(item)
        if self._wake is not None:
            self._wake.set()

    # ---- the publisher's task ---------------------------------------------------------------
    async def run(self, service: TwinService) -> None:
        """Drain the outbox; every :data:`STATUS_S` publish each machine's status."""
        self._wake = asyncio.Event()
        next_status = time.monotonic()
        while True:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._wake.wait(), max(0.0, next_status - time.monotonic()))
            self._wake.clear()
            if self._state_changed(service):  # before the rows it changed with: a client
                await self.statuses(service)  # reading both never sees rows of a "waiting" one
                next_status = time.monotonic() + STATUS_S
            await self.drain(service)
            if time.monotonic() >= next_status:
                await self.statuses(service)
                next_status = time.monotonic() + STATUS_S

    def _state_changed(self, service: TwinService) -> bool:
        """A machine's state (live, waiting, silent, ...) differs from the one last sent."""
        return any(self._state_sent.get(st.twin.name) != st.state for st in service.states.values())

    async def drain(self, service: TwinService) -> None:
        while self.outbox:
            what, item = self.outbox.popleft()
            st = service.states.get(item.machine)
            if st is None:
                continue
            try:
                if what == "prediction":
                    await self._guard(self.send_prediction(st, item))
                else:
                    await self._guard(self.send_alarm(st, item))
            except asyncio.CancelledError:  # stopped while sending: close() sends it again
                self.outbox.appendleft((what, item))
                raise
            await asyncio.sleep(0)  # let the samples waiting in the loop go first

    async def statuses(self, service: TwinService, state: str | None = None) -> None:
        assert self.health is not None
        for st in service.states.values():
            self._state_sent[st.twin.name] = state or st.state
            await self._guard(self.send_status(st, self.health.status(st, state)))
            doc = sliver(st)  # the sliver and the leveller's recommendation, when they change
            if doc is None:
                continue
            same = {k: v for k, v in doc.items() if k not in ("time", "timestamp")}
            if self._sliver_sent.get(st.twin.name) != same:
                self._sliver_sent[st.twin.name] = same
                await self._guard(self.send_sliver(st, doc))

    async def _guard(self, send: Any) -> None:
        try:
            await send
            self.sent += 1
        except Exception as exc:  # noqa: BLE001 - a client gone must not stop the twin
            self.failed += 1
            self.last_error = f"{type(exc).__name__}: {exc}"[:200]

    def summary(self) -> dict[str, Any]:
        return {"spec": self.spec, "sent": self.sent, "dropped": self.dropped,
                "failed": self.failed, "last_error": self.last_error or None}  # fmt: skip

    # ---- a protocol's part --------------------------------------------------------------------
    async def open(self, service: TwinService) -> None:
        self.health = Health(service)
        self.service = service

    async def close(self, service: TwinService) -> None:
        """Publish the last entries and each machine's final status (offline), then close."""

    async def send_prediction(self, st: MachineState, row: SampleRow) -> None:
        raise NotImplementedError

    async def send_alarm(self, st: MachineState, ev: EventRow) -> None:
        raise NotImplementedError

    async def send_status(self, st: MachineState, status: dict[str, Any]) -> None:
        raise NotImplementedError

    async def send_sliver(self, st: MachineState, doc: dict[str, Any]) -> None:
        """The machine's sliver and leveller (:func:`~.payload.sliver`), when they change."""


__all__ = ["CLOSE_S", "QUEUE_LEN", "STATUS_S", "Publisher"]
