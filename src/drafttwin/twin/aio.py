"""Running the twin's event loop with a bounded shutdown.

``asyncio.run`` cancels every task left at the end and waits for each to finish, without a
limit. A client library that leaves a task which does not end on cancellation (asyncua did,
after a server refused a secured session) would then hold the process forever. The twin
cancels what is left, waits a grace period, and closes the loop regardless.
"""

from __future__ import annotations

import asyncio
import contextlib
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
            pending = [t for t in asyncio.all_tasks(loop) if not t.done()]
            for task in pending:
                task.cancel()
            if pending:
                loop.run_until_complete(asyncio.wait(pending, timeout=grace_s))
            with contextlib.suppress(Exception):
                loop.run_until_complete(
                    asyncio.wait_for(loop.shutdown_asyncgens(), timeout=grace_s)
                )
        finally:
            loop.close()
