"""A clean stop of MQTT publishers: each machine's ``offline`` (retained), then disconnect.

The acknowledgements are awaited together and on the event loop, within one bound: an
embedded broker runs on that loop, so a blocking wait per machine (paho's
``wait_for_publish``) could never see its acknowledgement and took its whole timeout, 2 s a
machine (three machines stopped in over 6 s; SIGTERM must end a command within 5 s).
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Sequence
from typing import Any

from drafttwin.wire.conventions import OFFLINE, status_topic

CLOSE_WAIT_S = 1.5
"""How long all the ``offline`` messages together may wait for their acknowledgements."""


async def say_offline_and_close(clients: Sequence[tuple[str, Any]],
                                wait_s: float = CLOSE_WAIT_S) -> None:  # fmt: skip
    """Publish ``offline`` for each ``(machine name, paho client)``, wait for the brokers'
    acknowledgements up to ``wait_s`` in all, then disconnect every client."""
    sent = []
    for name, client in clients:
        if client is None:
            continue
        with contextlib.suppress(Exception):
            if client.is_connected():
                sent.append(client.publish(status_topic(name), OFFLINE, qos=1, retain=True))
    deadline = time.monotonic() + wait_s
    while sent and time.monotonic() < deadline:
        with contextlib.suppress(Exception):
            sent = [info for info in sent if not info.is_published()]
        await asyncio.sleep(0.02)
    for _, client in clients:
        if client is None:
            continue
        with contextlib.suppress(Exception):
            client.disconnect()
            client.loop_stop()
