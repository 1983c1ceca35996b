"""Running the twin's event loop with a bounded shutdown, stopped cleanly by signals.

``asyncio.run`` cancels every task left at the end and waits for each to finish, without a
limit. A client library that leaves a task which does not end on cancellation (asyncua did,
after a server refused a secured session) would then hold the process forever. The twin
cancels what is left, waits a grace period, and closes the loop regardless.

:func:`run_until_signal` is how a long-running command (``twin run``, ``plant serve``) stops:
SIGINT and SIGTERM cancel its main task at the next ``await``, through the loop's own signal
handlers, instead of raising ``KeyboardInterrupt`` wherever the signal lands (inside a numba
kernel that became a ``SystemError`` and a traceback; inside the loop's teardown it left an
AnyIO worker thread alive and the process hanging after its summary).
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
import threading
from collections.abc import Coroutine
from typing import Any, TypeVar

T = TypeVar("T")

GRACE_S = 5.0
"""How long tasks left at the end may take to finish once cancelled."""


def run_bounded(coro: Coroutine[Any, Any, T], grace_s: float = GRACE_S) -> T:
    """Run ``coro`` to completion in a new event loop; then cancel the tasks still pending,
    wait at most ``grace_s`` for them and close the loop (what did not end is abandoned)."""
    loop = asyncio.new_event_loop()
    try:
        return loop.run_until_complete(coro)
    finally:
        try:
            _cancel_left(loop, grace_s)
        finally:
            loop.close()


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def run_until_signal(
    coro: Coroutine[Any, Any, T], grace_s: float = GRACE_S
) -> tuple[T | None, int | None]:
    """Run ``coro`` like :func:`run_bounded` until it ends or SIGINT/SIGTERM arrives; returns
    ``(result, None)``, or ``(None, signal number)`` when a signal cancelled it. Away from the
    main thread (no signal handlers there) it is :func:`run_bounded`."""
    if threading.current_thread() is not threading.main_thread():
        return run_bounded(coro, grace_s), None
    loop = asyncio.new_event_loop()
    task = loop.create_task(coro)
    received: list[int] = []

    def stop(signum: int) -> None:
        received.append(signum)
        task.cancel()

    for signum in STOP_SIGNALS:
        loop.add_signal_handler(signum, stop, signum)
    try:
        return loop.run_until_complete(task), None
    except asyncio.CancelledError:
        if not received:
            raise
        return None, received[0]
    finally:
        try:
            for signum in STOP_SIGNALS:
                loop.remove_signal_handler(signum)
            _cancel_left(loop, grace_s)
        finally:
            loop.close()


def _cancel_left(loop: asyncio.AbstractEventLoop, grace_s: float) -> None:
    pending = [t for t in asyncio.all_tasks(loop) if not t.done()]
    for task in pending:
        task.cancel()
    if pending:
        loop.run_until_complete(asyncio.wait(pending, timeout=grace_s))
    with contextlib.suppress(Exception):
        loop.run_until_complete(asyncio.wait_for(loop.shutdown_asyncgens(), timeout=grace_s))
    with contextlib.suppress(Exception):  # to_thread workers (AnyIO's stop with the task)
        loop.run_until_complete(asyncio.wait_for(loop.shutdown_default_executor(), timeout=grace_s))
