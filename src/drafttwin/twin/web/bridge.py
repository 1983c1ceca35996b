"""From the page's thread to the twin's loop: the one way a web handler touches the twin.

The page (uvicorn, FastAPI, JSON, WebSockets) runs in a thread and event loop of its own, so that
viewers never queue in front of the samples: 100 clients hammering ``/api/history`` kept a twin
sharing its loop with them at 100 rows/s but let its data age reach 0.95 s (p99). What a handler
needs from the twin's state, it asks the twin's loop for (:meth:`Bridge.call`): the loop runs
the short function between two samples and nothing of HTTP. Snapshots many clients ask for
(status, machines, alarms) are shared for :data:`SNAPSHOT_S`, so that the twin computes at most
a few of them a second however many clients ask.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import time
from collections.abc import Callable
from typing import Any, TypeVar

from fastapi import HTTPException

T = TypeVar("T")

SNAPSHOT_S = 0.1
"""A shared snapshot is reused for this long, s (the page polls every second)."""
CALL_TIMEOUT_S = 5.0
"""A call the twin's loop has not answered in this long gets 503."""


class Bridge:
    """Runs functions on the twin's event loop for handlers on another (``loop`` None: the
    handlers run on the twin's loop themselves, as under a test client, and call directly)."""

    def __init__(self, loop: asyncio.AbstractEventLoop | None = None) -> None:
        self.loop = loop
        self._shared: dict[str, tuple[float, asyncio.Future[Any]]] = {}

    async def call(self, fn: Callable[..., T], *args: Any) -> T:
        """``fn(*args)`` on the twin's loop; its result or its exception (an HTTPException
        passes as it is) here."""
        if self.loop is None or self.loop is asyncio.get_running_loop():
            return fn(*args)
        done: concurrent.futures.Future[T] = concurrent.futures.Future()

        def run() -> None:
            if not done.set_running_or_notify_cancel():
                return
            try:
                done.set_result(fn(*args))
            except BaseException as exc:  # noqa: BLE001 - handed to the handler that asked
                done.set_exception(exc)

        try:
            self.loop.call_soon_threadsafe(run)
        except RuntimeError:  # the twin's loop is closed: the twin is stopping
            raise HTTPException(503, "the twin is stopping") from None
        try:
            return await asyncio.wait_for(asyncio.wrap_future(done), CALL_TIMEOUT_S)
        except TimeoutError:
            raise HTTPException(
                503, f"the twin did not answer within {CALL_TIMEOUT_S:g} s"
            ) from None

    async def shared(self, key: str, fn: Callable[[], T]) -> T:
        """``fn()`` on the twin's loop, its result shared by every request for ``key`` within
        :data:`SNAPSHOT_S` (the result must not be changed by its readers; ``key`` is one of
        a few fixed names, never taken from a request)."""
        now = time.monotonic()
        got = self._shared.get(key)
        if got is None or not _fresh(got, now):
            got = (now, asyncio.ensure_future(self.call(fn)))
            self._shared[key] = got
        result: T = await asyncio.shield(got[1])
        return result


def _fresh(got: tuple[float, asyncio.Future[Any]], now: float) -> bool:
    """Whether a shared snapshot may still be handed out: younger than :data:`SNAPSHOT_S`, of
    this event loop (a test client opens one per request) and not a failure (the next request
    asks again)."""
    made, snap = got
    if now - made >= SNAPSHOT_S or snap.get_loop() is not asyncio.get_running_loop():
        return False
    return not (snap.done() and (snap.cancelled() or snap.exception() is not None))


__all__ = ["CALL_TIMEOUT_S", "SNAPSHOT_S", "Bridge"]
