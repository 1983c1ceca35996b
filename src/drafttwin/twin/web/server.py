"""The twin's page served beside its processing: uvicorn in a thread and event loop of its own.

The twin's loop receives, steps, diagnoses and stores the samples; the page's loop parses HTTP,
runs the routes, encodes JSON and feeds the WebSockets. They meet only through
:class:`~drafttwin.twin.web.bridge.Bridge` (short calls on the twin's loop), the hub's lock
(processed rows handed over) and the history's own threads and DuckDB connections. A hundred
clients asking as fast as they are answered then wait on each other, not on the machine.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import threading
import time
from typing import Any

from drafttwin.twin.service import TwinService
from drafttwin.twin.web.app import PUSH_S, Hub, create_app

WEB_STOP_S = 1.0
"""At a stop, how long the page's server may take to close."""


def bound_socket(bind: tuple[str, int]) -> socket.socket:
    """A TCP socket bound to ``bind`` (IPv6 when the host has a colon) for uvicorn to serve on;
    an address in use fails here, as an OSError the CLI reports."""
    family = socket.AF_INET6 if ":" in bind[0] else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(bind)
    except OSError:
        sock.close()
        raise
    return sock


async def _pump(hub: Hub) -> None:
    while True:
        await asyncio.sleep(PUSH_S)
        hub.flush()


class PageThread:
    """uvicorn and the WebSocket pump of ``app`` on ``sock``, in a thread of their own."""

    def __init__(self, app: Any, sock: socket.socket) -> None:
        import uvicorn

        config = uvicorn.Config(app, log_level="warning", ws_max_size=1 << 16, lifespan="off")
        self.server = uvicorn.Server(config)
        self.app, self.sock = app, sock
        self.error: BaseException | None = None
        self.loop: asyncio.AbstractEventLoop | None = None
        self.thread = threading.Thread(target=self._run, name="twin-page", daemon=True)

    def _run(self) -> None:
        try:
            asyncio.run(self._serve())
        except BaseException as exc:  # noqa: BLE001 - reported by the twin's loop
            self.error = exc

    async def _serve(self) -> None:
        self.loop = asyncio.get_running_loop()
        pump = asyncio.create_task(_pump(self.app.state.hub))
        try:
            await self.server.serve(sockets=[self.sock])
        finally:
            pump.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await pump

    async def started(self) -> None:
        """Wait (on the twin's loop) until the server listens; its error if it failed."""
        self.thread.start()
        while not self.server.started:
            if not self.thread.is_alive():
                raise self.error or OSError("the page's server ended before it started")
            await asyncio.sleep(0.02)

    async def stop(self) -> None:
        """Stop listening, let the answers in progress go out for half of
        :data:`WEB_STOP_S`, then close every connection (open WebSockets and keep-alive
        clients do not hold the stop); wait at most :data:`WEB_STOP_S` for the thread."""
        quiet = _QuietCancellations()
        uvicorn_log = logging.getLogger("uvicorn.error")
        uvicorn_log.addFilter(quiet)
        start = time.monotonic()
        self.server.should_exit = True
        await self._joined(start + WEB_STOP_S / 2)
        self.server.force_exit = True
        if await self._joined(start + WEB_STOP_S):
            self.sock.close()
            uvicorn_log.removeFilter(quiet)

    async def _joined(self, deadline: float) -> bool:
        """Whether the thread ended by ``deadline`` (monotonic), waiting on this loop."""
        while self.thread.is_alive() and time.monotonic() < deadline:
            await asyncio.sleep(0.02)
        return not self.thread.is_alive()


class _QuietCancellations(logging.Filter):
    """While a page stops, a request still running is cancelled with its loop: uvicorn
    would log that as 'Exception in ASGI application' with a traceback; it is the stop."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        return not isinstance(exc, asyncio.CancelledError)


async def serve_with(service: TwinService, bind: tuple[str, int], token: str | None,
                     duration_s: float | None, max_rows: int | None,
                     started: Any = None) -> None:  # fmt: skip
    """Run ``service`` on this loop and its page on ``bind`` in a thread, until the service
    stops; ``started(page)`` (the :class:`PageThread`) once the page listens."""
    sock = bound_socket(bind)
    app = create_app(service, token, twin_loop=asyncio.get_running_loop())
    page = PageThread(app, sock)
    try:
        await page.started()
        if started is not None:
            started(page)
        await service.run(duration_s=duration_s, max_rows=max_rows)
    finally:
        # the history first: its queries answer 'stopping' (503) while the page still serves
        app.state.history.close()
        await page.stop()


__all__ = ["WEB_STOP_S", "PageThread", "bound_socket", "serve_with"]
