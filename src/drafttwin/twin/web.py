"""The twin's page, REST API, WebSocket live stream and Prometheus metrics (FastAPI + uvicorn).

Routes (all under the token when one is set: ``Authorization: Bearer TOKEN``, ``?token=TOKEN``
or the ``drafttwin_token`` cookie the page sets):

* ``GET /``: the page (charts by uPlot, shipped in the package: no CDN).
* ``GET /api/machines``, ``/api/status``, ``/api/model/{machine}``, ``/api/alarms``,
  ``/api/kinematics/{machine}``, ``/api/history/{machine}?seconds=30``.
* ``WS /ws``: every processed row of every machine, batched every 50 ms.
* ``GET /metrics``: Prometheus text (samples in, latency, dropped payloads, alarms, source state).
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import math
import socket
import time
from importlib import resources
from typing import Any

from fastapi import WebSocket  # at module level: FastAPI resolves the handler's annotation here

from drafttwin._json import to_strict
from drafttwin.twin.service import TwinService
from drafttwin.twin.store import EventRow, SampleRow

PUSH_S = 0.05
"""WebSocket batching interval, s (20 updates per second)."""
MAX_WS_QUEUE = 2000
"""Batches kept per WebSocket client; a client too slow to read them loses the oldest."""
LATENCY_BUCKETS = (0.0005, 0.001, 0.002, 0.005, 0.01, 0.015, 0.02, 0.03, 0.05, 0.1, 0.25, 1.0)


class Metrics:
    """Prometheus metrics of one service, in their own registry."""

    def __init__(self) -> None:
        from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram

        self.registry = CollectorRegistry()
        self.samples = Counter("drafttwin_samples", "Samples processed", ["machine"],
                               registry=self.registry)  # fmt: skip
        self.drops = Counter("drafttwin_dropped_payloads", "Malformed payloads dropped",
                             ["machine"], registry=self.registry)  # fmt: skip
        self.alarms = Counter("drafttwin_events", "Events (gaps, reconnects, alarms)",
                              ["machine", "kind"], registry=self.registry)  # fmt: skip
        self.latency = Histogram("drafttwin_latency_seconds",
                                 "Sample received to prediction stored and pushed",
                                 buckets=LATENCY_BUCKETS, registry=self.registry)  # fmt: skip
        self.source_up = Gauge("drafttwin_source_up", "1 while the machine's source delivers",
                               ["machine"], registry=self.registry)  # fmt: skip
        self.causes = Counter("drafttwin_fault_causes", "Fault alarms localised, by the most "
                              "probable cause (element:kind; none when not localised)",
                              ["machine", "cause"], registry=self.registry)  # fmt: skip
        self.sliver_count = Gauge("drafttwin_sliver_count_ktex", "Running mean count of the "
                                  "delivered sliver, ktex", ["machine"], registry=self.registry)  # fmt: skip
        self.sliver_cv = Gauge("drafttwin_sliver_cv_percent", "Running CV of the delivery "
                               "sensor's readings, %", ["machine"], registry=self.registry)  # fmt: skip

    def cause(self, machine: str, cause: str) -> None:
        self.causes.labels(machine, cause).inc()

    def observe(self, machine: str, rows: int, latency_s: float) -> None:
        self.samples.labels(machine).inc(rows)
        self.latency.observe(latency_s)

    def dropped(self, machine: str, count: int = 1) -> None:
        self.drops.labels(machine).inc(count)

    def event(self, ev: EventRow) -> None:
        self.alarms.labels(ev.machine, ev.kind).inc()

    def text(self, service: TwinService) -> bytes:
        from prometheus_client import generate_latest

        for name, st in service.states.items():
            self.source_up.labels(name).set(1.0 if st.state == "live" else 0.0)
            if st.sliver is not None and st.sliver.cv_pct == st.sliver.cv_pct:
                self.sliver_count.labels(name).set(st.sliver.count_ktex)
                self.sliver_cv.labels(name).set(st.sliver.cv_pct)
        return bytes(generate_latest(self.registry))


def _row(r: SampleRow) -> list[Any]:
    return [r.ts_us / 1e6, r.seq, r.setpoint, *r.measured, *r.physics, *r.twin, *r.residual]


FAULT_KINDS = ("fault", "fault-cause", "sensor-fault")
"""Events whose detail is JSON (the alarm and its probable cause): parsed into ``fault``."""


def _event(e: EventRow) -> dict[str, Any]:
    out = {"machine": e.machine, "kind": e.kind, "time": e.ts_us / 1e6, "detail": e.detail}
    if e.kind in FAULT_KINDS:
        with contextlib.suppress(ValueError):
            out["fault"] = json.loads(e.detail)
    return out


class Hub:
    """Collects processed rows and pushes them to the WebSocket clients every ``PUSH_S``."""

    def __init__(self) -> None:
        self.clients: set[asyncio.Queue[str]] = set()
        self.rows: dict[str, list[list[Any]]] = {}
        self.events: list[dict[str, Any]] = []

    def add(self, machine: str, rows: list[SampleRow], events: list[EventRow]) -> None:
        if not self.clients:
            return
        self.rows.setdefault(machine, []).extend(_row(r) for r in rows)
        self.events.extend(_event(e) for e in events)

    def flush(self) -> None:
        if not (self.rows or self.events) or not self.clients:
            return
        text = json.dumps(to_strict({"rows": self.rows, "events": self.events}), allow_nan=False)
        self.rows, self.events = {}, []
        for q in self.clients:
            if q.qsize() >= MAX_WS_QUEUE:
                with contextlib.suppress(asyncio.QueueEmpty):
                    q.get_nowait()
            q.put_nowait(text)


def _check(token: str | None, given: str | None) -> bool:
    return token is None or (given is not None and hmac.compare_digest(token, given))


def _given(headers: Any, query: Any, cookies: Any) -> str | None:
    auth = headers.get("authorization", "")
    if auth.lower().startswith("bearer "):
        return str(auth[7:].strip())
    return query.get("token") or cookies.get("drafttwin_token")


def create_app(service: TwinService, token: str | None = None) -> Any:
    """The FastAPI app of ``service`` (a token, if given, guards every route)."""
    from fastapi import FastAPI, HTTPException, Request, WebSocketDisconnect
    from fastapi.responses import HTMLResponse, Response
    from starlette.middleware.base import BaseHTTPMiddleware

    app = FastAPI(title="drafttwin live twin", docs_url=None, redoc_url=None)
    hub = Hub()
    metrics = Metrics()
    service.metrics = metrics
    service.subscribers.append(hub.add)
    service.event_hooks.append(metrics.event)
    static = resources.files("drafttwin.twin") / "static"

    class TokenGuard(BaseHTTPMiddleware):
        async def dispatch(self, request: Request, call_next: Any) -> Any:
            if not _check(token, _given(request.headers, request.query_params, request.cookies)):
                return Response("token required", status_code=401)
            response = await call_next(request)
            if token is not None and request.query_params.get("token"):
                response.set_cookie("drafttwin_token", token, httponly=True, samesite="strict")
            return response

    app.add_middleware(TokenGuard)

    def state(machine: str) -> Any:
        st = service.states.get(machine)
        if st is None:
            raise HTTPException(404, f"no machine {machine!r}")
        return st

    @app.get("/", response_class=HTMLResponse)
    def page() -> str:
        return (static / "index.html").read_text(encoding="utf-8")

    @app.get("/static/{name}")
    def asset(name: str) -> Response:
        kinds = {"uPlot.iife.min.js": "text/javascript", "uPlot.min.css": "text/css",
                 "twin.js": "text/javascript", "uPlot.LICENSE": "text/plain"}  # fmt: skip
        if name not in kinds:
            raise HTTPException(404, "no such file")
        return Response((static / name).read_bytes(), media_type=kinds[name])

    @app.get("/api/machines")
    def machines() -> list[dict[str, Any]]:
        return [{"machine": n, "channels": list(st.mapping.channels), "state": st.state,
                 "source": st.source, "rate_hz": st.mapping.rate_hz}
                for n, st in service.states.items()]  # fmt: skip

    @app.get("/api/status")
    def status() -> Any:
        return to_strict(service.status())

    @app.get("/api/model/{machine}")
    def model(machine: str) -> Any:
        st = state(machine)
        m = st.twin.model
        return to_strict({"machine": machine, "model": m.name, "class": type(m).__name__,
                          "channels": list(m.channels_), "horizon": m.task.horizon,
                          "sample_rate_hz": getattr(m, "sample_rate_hz_", None),
                          "mechanistic": (getattr(m, "mechanistic_spec_", None) or {}).get("kind"),
                          "physics": "reduced" if st.twin.train.reduction is not None else "full",
                          "file": str(st.mapping.model) if st.mapping.model else None})  # fmt: skip

    @app.get("/api/alarms")
    def alarms() -> list[dict[str, Any]]:
        out = [_event(e) for st in service.states.values() for e in st.alarms]
        return sorted(out, key=lambda e: e["time"])

    @app.get("/api/kinematics/{machine}")
    def kinematics(machine: str) -> Any:
        from drafttwin.mechanics import Signal
        from drafttwin.mechanics.kinematics import operating_point

        st = state(machine)
        supply = st.twin.last_setpoint
        train = st.twin.train
        if math.isfinite(supply):
            train = train.with_supply_schedule(Signal(0.0, 1.0, [supply, supply]))  # type: ignore[arg-type]
        op = operating_point(train)
        return to_strict({"machine": machine, "supply_hz": supply, "motor_rpm": op.motor_rpm,
                          "slip": op.slip, "roller_rpm": op.roller_rpm})  # fmt: skip

    @app.get("/api/history/{machine}")
    def history(machine: str, seconds: float = 30.0) -> Any:
        st = state(machine)
        if not (math.isfinite(seconds) and 0 < seconds <= 3600):
            raise HTTPException(422, "seconds must be > 0 and <= 3600")
        rows = list(st.recent)
        if rows:
            cut = rows[-1].ts_us - seconds * 1e6
            rows = [r for r in rows if r.ts_us >= cut]
        return to_strict({"machine": machine, "channels": list(st.mapping.channels),
                          "columns": ["time", "seq", "supply_hz", "measured...", "physics...",
                                      "twin...", "residual..."],
                          "rows": [_row(r) for r in rows]})  # fmt: skip

    @app.get("/metrics")
    def prometheus() -> Response:
        return Response(metrics.text(service), media_type="text/plain; version=0.0.4")

    @app.websocket("/ws")
    async def stream(ws: WebSocket) -> None:
        if not _check(token, _given(ws.headers, ws.query_params, ws.cookies)):
            await ws.close(code=1008)
            return
        await ws.accept()
        q: asyncio.Queue[str] = asyncio.Queue()
        hub.clients.add(q)
        try:
            while True:
                await ws.send_text(await q.get())
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            hub.clients.discard(q)

    app.state.hub = hub
    return app


async def _pump(hub: Hub, stop: asyncio.Event) -> None:
    while not stop.is_set():
        await asyncio.sleep(PUSH_S)
        hub.flush()


async def serve_with(service: TwinService, bind: tuple[str, int], token: str | None,
                     duration_s: float | None, max_rows: int | None,
                     started: Any = None) -> None:  # fmt: skip
    """Run ``service`` and its page on ``bind`` until the service stops."""
    import uvicorn

    app = create_app(service, token)
    family = socket.AF_INET6 if ":" in bind[0] else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind(bind)  # an address in use fails here, as an OSError the CLI reports
    config = uvicorn.Config(app, log_level="warning", ws_max_size=1 << 16, lifespan="off")
    server = uvicorn.Server(config)
    stop = asyncio.Event()
    web = asyncio.create_task(server.serve(sockets=[sock]))
    pump = asyncio.create_task(_pump(app.state.hub, stop))
    try:
        while not server.started:
            if web.done():
                web.result()  # the bind failed: raise its error
                raise OSError(f"cannot serve on {bind[0]}:{bind[1]}")
            await asyncio.sleep(0.02)
        if started is not None:
            started(server)
        await service.run(duration_s=duration_s, max_rows=max_rows)
    finally:
        stop.set()
        server.should_exit = True
        start = time.monotonic()
        while not web.done() and time.monotonic() - start < 5:
            await asyncio.sleep(0.05)
        for task in (web, pump):
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task


__all__ = ["Hub", "Metrics", "create_app", "serve_with"]
