"""The twin's page, REST API, WebSocket live stream and Prometheus metrics (FastAPI + uvicorn).

Routes (all under the token when one is set: ``Authorization: Bearer TOKEN``, ``?token=TOKEN``
or the ``drafttwin_token`` cookie the page sets):

* ``GET /``: the page (charts by uPlot, shipped in the package: no CDN).
* ``GET /api/machines``, ``/api/status``, ``/api/model/{machine}``, ``/api/alarms`` (alarms
  only), ``/api/events`` (the other events), ``/api/kinematics/{machine}``,
  ``/api/history/{machine}`` (the store's whole range, paged and bounded: :mod:`~drafttwin.twin.web.history`).
* ``GET /openapi.json`` and ``/docs``: the schema and FastAPI's interactive docs.
* ``WS /ws``: every processed row of every machine, batched every 50 ms; what a client sends
  is bounded (size and rate) and dropped.
* ``GET /metrics``: Prometheus text (:mod:`~drafttwin.twin.web.metrics`).

The token guard is :mod:`~drafttwin.twin.web.guard`, the same for the hall's page.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import re
import threading
import time
from collections.abc import Callable
from typing import Any

# at module level: with postponed annotations FastAPI resolves the handlers' annotations in
# this module's namespace (a Response imported inside create_app broke /openapi.json: 500)
from fastapi import FastAPI, HTTPException, WebSocket, WebSocketDisconnect
from fastapi.responses import HTMLResponse, Response

from drafttwin._json import to_strict
from drafttwin.twin import commands
from drafttwin.twin.service import TwinService
from drafttwin.twin.store.db import EventRow, SampleRow
from drafttwin.twin.web.assets import page_text, serve_docs, serve_static
from drafttwin.twin.web.bridge import Bridge
from drafttwin.twin.web.guard import guard, ws_admits
from drafttwin.twin.web.history import FAULT_KINDS, HistoryApi
from drafttwin.twin.web.history import event_dict as _event
from drafttwin.twin.web.metrics import LATENCY_BUCKETS, Metrics

PUSH_S = 0.05
"""WebSocket batching interval, s (20 updates per second)."""
MAX_WS_QUEUE = 2000
"""Batches kept per WebSocket client; a client too slow to read them loses the oldest."""
WS_IN_MAX_BYTES = 4096
"""Largest message a WebSocket client may send (the page sends none); larger: closed, 1009."""
WS_IN_RATE_HZ = 5.0
WS_IN_BURST = 20
"""Client messages: a burst of 20, then 5 per second; a client sending more is closed, 1008."""


def _row(r: SampleRow) -> list[Any]:
    return [r.ts_us / 1e6, r.seq, r.setpoint, *r.measured.tolist(), *r.physics.tolist(),
            *r.twin.tolist(), *r.residual.tolist()]  # fmt: skip


_NONFINITE = re.compile(r"(?<=[\[ ])(?:-?Infinity|NaN)(?=[,\]])")
"""A non-finite number in a list of numbers as ``json.dumps`` writes it (never in a string)."""


def _numbers_json(rows: list[list[Any]]) -> str:
    """Rows of numbers as strict JSON (NaN -> null) without walking them in Python."""
    return _NONFINITE.sub("null", json.dumps(rows))


def _push_json(rows: dict[str, list[list[Any]]], events: list[dict[str, Any]]) -> str:
    machines = ", ".join(f"{json.dumps(m)}: {_numbers_json(r)}" for m, r in rows.items())
    return f'{{"rows": {{{machines}}}, "events": {json.dumps(to_strict(events), allow_nan=False)}}}'


class Hub:
    """Collects processed rows (on the twin's loop) and pushes them to the WebSocket clients
    every ``PUSH_S`` (on the page's loop): the JSON is made on the page's side of the lock."""

    def __init__(self) -> None:
        self.clients: set[asyncio.Queue[str]] = set()
        self.rows: dict[str, list[list[Any]]] = {}
        self.events: list[dict[str, Any]] = []
        self._lock = threading.Lock()

    def add(self, machine: str, rows: list[SampleRow], events: list[EventRow]) -> None:
        if not self.clients:
            return
        got, seen = [_row(r) for r in rows], [_event(e) for e in events]
        with self._lock:
            self.rows.setdefault(machine, []).extend(got)
            self.events.extend(seen)

    def flush(self) -> None:
        with self._lock:
            if not (self.rows or self.events):
                return
            rows, events = self.rows, self.events
            self.rows, self.events = {}, []
        if not self.clients:
            return
        text = _push_json(rows, events)
        for q in list(self.clients):
            if q.qsize() >= MAX_WS_QUEUE:
                with contextlib.suppress(asyncio.QueueEmpty):
                    q.get_nowait()
            q.put_nowait(text)


def _answer(command: Callable[..., Any], *args: Any) -> Any:
    """An operator's command (:mod:`drafttwin.twin.commands`), its refusal as the HTTP error."""
    try:
        return command(*args)
    except commands.Refused as exc:
        raise HTTPException(exc.status, exc.text) from None


def create_app(service: TwinService, token: str | None = None,
               twin_loop: asyncio.AbstractEventLoop | None = None) -> FastAPI:  # fmt: skip
    """The FastAPI app of ``service`` (a token, if given, guards every route). Its OpenAPI
    schema is ``/openapi.json``, the interactive docs ``/docs``. Served on a loop other than
    ``twin_loop`` (:mod:`~drafttwin.twin.web.server`), its handlers read and change the twin's
    state only through a :class:`~drafttwin.twin.web.bridge.Bridge` to that loop."""
    app = FastAPI(title="drafttwin live twin", summary="The live twin's REST API, WebSocket "
                  "and metrics (docs/twin.md)", docs_url=None, redoc_url=None)  # fmt: skip
    hub = Hub()
    metrics = Metrics(service)
    bridge = Bridge(twin_loop)
    api = HistoryApi(service, bridge)
    service.metrics = metrics
    service.subscribers.append(hub.add)
    service.event_hooks.append(metrics.event)
    guard(app, token)

    def state(machine: str) -> Any:
        st = service.states.get(machine)
        if st is None:
            raise HTTPException(404, f"no machine {machine[:100]!r}")
        return st

    @app.get("/", response_class=HTMLResponse, include_in_schema=False)
    def page() -> str:
        return page_text("index.html")

    serve_static(app)
    serve_docs(app)

    @app.get("/api/machines")
    async def machines() -> list[dict[str, Any]]:
        """Each machine: its channels, state, source and sample rate."""
        return await bridge.shared("machines", lambda: [
            {"machine": n, "channels": list(st.mapping.channels), "state": st.state,
             "source": st.source, "rate_hz": st.mapping.rate_hz}
            for n, st in service.states.items()])  # fmt: skip

    @app.get("/api/status")
    async def status() -> Any:
        """Rows, latency percentiles, the store, and per machine its counts and last alarm."""
        return await bridge.shared("status", lambda: to_strict(service.status()))

    @app.post("/api/machines/{machine}/relearn")
    async def relearn(machine: str) -> Any:
        """After maintenance: forget the machine's learned healthy state and learn it again
        (no fault alarm meanwhile); its detector's state afterwards."""
        return await bridge.call(lambda: _answer(commands.relearn, service, machine,
                                                 "operator's command (REST)"))  # fmt: skip

    @app.get("/api/alarms/active")
    async def active_alarms(machine: str | None = None) -> Any:
        """The alarms that are active or wait for an operator (acknowledge, confirm), most
        severe first, each with its cause: what the page's banner shows."""

        def retained() -> Any:
            if machine is not None:
                state(machine)
            return to_strict([a.to_dict() for a in service.book.retained(machine)])

        return await bridge.call(retained)

    @app.post("/api/machines/{machine}/alarms/{what}")
    async def acknowledge(machine: str, what: str, comment: str = "",
                          alarm: str | None = None) -> Any:  # fmt: skip
        """``what`` = acknowledge or confirm (those acknowledged) the machine's retained alarms,
        or the one whose id is ``alarm`` (an operator's, as over OPC UA); the alarms after."""
        return await bridge.call(lambda: _answer(commands.take_alarms, service, machine, what,
                                                 comment, alarm))  # fmt: skip

    @app.get("/api/model/{machine}")
    async def model(machine: str) -> Any:
        """The machine's model: class, channels, horizon, physics."""
        st = await bridge.call(state, machine)
        m = st.twin.model
        return to_strict({"machine": machine, "model": m.name, "class": type(m).__name__,
                          "channels": list(m.channels_), "horizon": m.task.horizon,
                          "sample_rate_hz": getattr(m, "sample_rate_hz_", None),
                          "mechanistic": (getattr(m, "mechanistic_spec_", None) or {}).get("kind"),
                          "physics": "reduced" if st.twin.train.reduction is not None else "full",
                          "file": str(st.mapping.model) if st.mapping.model else None})  # fmt: skip

    @app.get("/api/alarms")
    async def alarms(machine: str | None = None, start: str | None = None,
                     end: str | None = None, limit: int | None = None) -> Response:  # fmt: skip
        """Alarms only (fault, its probable cause, sensor fault, sliver chimney), oldest first:
        the newest ``limit`` (default 200, at most 1000) in ``start .. end`` (epoch seconds or
        ISO 8601), from the store when the twin has one."""
        return await api.events(True, machine, start, end, limit)

    @app.get("/api/events")
    async def events(machine: str | None = None, start: str | None = None,
                     end: str | None = None, limit: int | None = None) -> Response:  # fmt: skip
        """The other events (gaps, reconnects, dropped payloads, silent sources, history
        recovered), as ``/api/alarms``."""
        return await api.events(False, machine, start, end, limit)

    @app.get("/api/kinematics/{machine}")
    def kinematics(machine: str) -> Any:
        """The operating point at the machine's current set-point."""
        from drafttwin.mechanics import Signal
        from drafttwin.mechanics.steady_state import operating_point

        st = state(machine)
        supply = st.twin.last_setpoint
        train = st.twin.train
        if math.isfinite(supply):
            train = train.with_supply_schedule(Signal(0.0, 1.0, [supply, supply]))  # type: ignore[arg-type]
        op = operating_point(train)
        return to_strict({"machine": machine, "supply_hz": supply, "motor_rpm": op.motor_rpm,
                          "slip": op.slip, "roller_rpm": op.roller_rpm})  # fmt: skip

    @app.get("/api/history/{machine}")
    async def history(machine: str, seconds: float | None = None, start: str | None = None,
                      end: str | None = None, limit: int | None = None, cursor: str | None = None,
                      points: int | None = None) -> Response:  # fmt: skip
        """Samples from the store, its whole range: the newest ``seconds``, or ``start .. end``
        (epoch seconds or ISO 8601); ``limit`` rows a page (default 5000, at most 10000), the
        rest from ``cursor`` = the answer's ``next``; ``points`` = N gives min and max per
        bucket (2N rows) for a long range. Without a store: the rows kept in memory."""
        if seconds is None and start is None and end is None and cursor is None:
            seconds = 30.0  # the page's first view
        return await api.history(machine, seconds, start, end, limit, cursor, points)

    @app.get("/metrics")
    async def prometheus() -> Response:
        """Prometheus exposition (read on the twin's loop, where the state does not move
        meanwhile; one read shared by the scrapes of a tenth of a second)."""
        text = await bridge.shared("metrics", metrics.text)
        return Response(text, media_type="text/plain; version=0.0.4")

    @app.websocket("/ws")
    async def stream(ws: WebSocket) -> None:
        if not ws_admits(token, ws):
            await ws.close(code=1008)
            return
        await ws.accept()
        q: asyncio.Queue[str] = asyncio.Queue()
        hub.clients.add(q)
        send = asyncio.create_task(_send(ws, q))
        read = asyncio.create_task(_read_bounded(ws))
        try:
            done, _ = await asyncio.wait({send, read}, return_when=asyncio.FIRST_COMPLETED)
            if read in done and not read.cancelled() and read.exception() is None:
                closing = read.result()
                if closing is not None:
                    with contextlib.suppress(Exception):
                        await ws.close(code=closing[0], reason=closing[1])
        finally:
            hub.clients.discard(q)
            for task in (send, read):
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await task

    app.state.hub = hub
    app.state.history = api
    app.state.bridge = bridge
    return app


async def _send(ws: WebSocket, q: asyncio.Queue[str]) -> None:
    with contextlib.suppress(WebSocketDisconnect, RuntimeError):
        while True:
            await ws.send_text(await q.get())


async def _read_bounded(ws: WebSocket) -> tuple[int, str] | None:
    """Read what the client sends (and drop it): ``None`` when it leaves, or the close code
    and reason when it sends a message over :data:`WS_IN_MAX_BYTES` or faster than the
    token bucket allows (:data:`WS_IN_BURST`, then :data:`WS_IN_RATE_HZ`)."""
    tokens, last = float(WS_IN_BURST), time.monotonic()
    while True:
        try:
            msg = await ws.receive()
        except (WebSocketDisconnect, RuntimeError):
            return None
        if msg["type"] == "websocket.disconnect":
            return None
        now = time.monotonic()
        tokens, last = min(float(WS_IN_BURST), tokens + (now - last) * WS_IN_RATE_HZ), now
        size = len(msg.get("text") or "") + len(msg.get("bytes") or b"")
        if size > WS_IN_MAX_BYTES:
            return 1009, f"message over {WS_IN_MAX_BYTES} bytes"
        tokens -= 1.0
        if tokens < 0:
            return 1008, f"more than {WS_IN_RATE_HZ:g} messages per second"


__all__ = ["FAULT_KINDS", "LATENCY_BUCKETS", "PUSH_S", "Hub", "Metrics", "create_app"]
