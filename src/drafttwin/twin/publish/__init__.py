"""The twin publishes its own results: an OPC UA server and MQTT topics of its own
(``twin run --publish``). See docs/twin.md, "Publishing the twin's results".

``--publish`` values::

    opcua:opc.tcp://HOST:PORT[?hz=10]
    mqtt://HOST:PORT[?qos=1&hz=10&prefix=drafttwin/twin]

``hz`` bounds the predictions published per machine and second (wall clock); alarms and the
status (once a second) always go out.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Sequence
from urllib.parse import parse_qsl, urlsplit

from drafttwin.errors import ConfigError
from drafttwin.twin.publish.base import CLOSE_S, Publisher
from drafttwin.twin.service import TwinService

MAX_HZ = 100.0
"""The highest prediction rate a publisher may be asked for, per machine."""


def parse_publish(text: str) -> Publisher:
    """A ``--publish`` value as its publisher (nothing connects yet)."""
    from drafttwin.twin.publish.mqtt import PREFIX, MqttPublisher
    from drafttwin.twin.publish.opcua import OpcUaPublisher

    fix = "write opcua:opc.tcp://HOST:PORT or mqtt://HOST:PORT[?qos=1&hz=10]"
    url = text.removeprefix("opcua:")
    parts = urlsplit(url)
    expected = "opc.tcp" if text.startswith("opcua:") else "mqtt"
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme != expected or not parts.hostname or port is None:
        raise ConfigError(f"bad publish address {text!r}", where="--publish", fix=fix)
    query = dict(parse_qsl(parts.query, keep_blank_values=True))
    known = {"hz", "qos", "prefix"} if expected == "mqtt" else {"hz"}
    if unknown := sorted(set(query) - known):
        raise ConfigError(f"unknown option {unknown[0]!r} in {text!r}", where="--publish",
                          fix=f"use only {', '.join(sorted(known))}")  # fmt: skip
    hz = _number(query.get("hz", "10"), text, "hz", 0.0, MAX_HZ)
    if expected == "opc.tcp":
        return OpcUaPublisher(parts.hostname, port, max_hz=hz)
    qos = query.get("qos", "1")
    if qos not in ("0", "1"):
        raise ConfigError(f"qos={qos!r} in {text!r}", where="--publish", fix="use qos=0 or qos=1")
    prefix = query.get("prefix", PREFIX).strip("/")
    if not prefix or any(c in prefix for c in "+#"):
        raise ConfigError(f"bad topic prefix {prefix!r} in {text!r}", where="--publish",
                          fix="give a topic without wildcards, e.g. prefix=plant/twin")  # fmt: skip
    return MqttPublisher(parts.hostname, port, qos=int(qos), prefix=prefix, max_hz=hz)


def _number(value: str, text: str, name: str, low: float, high: float) -> float:
    try:
        x = float(value)
    except ValueError:
        x = float("nan")
    if not low < x <= high:
        raise ConfigError(f"{name}={value!r} in {text!r}", where="--publish",
                          fix=f"give {name} above {low:g} and at most {high:g}")  # fmt: skip
    return x


@contextlib.asynccontextmanager
async def publishing(service: TwinService, publishers: Sequence[Publisher]) -> AsyncIterator[None]:
    """Open ``publishers`` (their servers listen, their clients connect) and feed them the
    service's rows and events while the block runs; at its end publish what is left and
    each machine's offline status, then close (each within :data:`CLOSE_S`)."""
    opened: list[Publisher] = []
    tasks: list[asyncio.Task[None]] = []
    try:
        for pub in publishers:
            try:
                await pub.open(service)
            except OSError as exc:
                raise ConfigError(f"cannot publish on {pub.spec} ({exc.strerror or exc})",
                                  where="--publish", fix="choose a free port or a running "
                                  "broker") from None  # fmt: skip
            opened.append(pub)
            service.subscribers.append(pub.on_rows)
            service.event_hooks.append(pub.on_event)
            tasks.append(asyncio.create_task(pub.run(service)))
        yield
    finally:
        for task in tasks:
            task.cancel()
        if tasks:
            await asyncio.wait(tasks, timeout=CLOSE_S)
        for pub in opened:
            service.subscribers.remove(pub.on_rows)
            service.event_hooks.remove(pub.on_event)
        await asyncio.gather(*(asyncio.wait_for(p.close(service), CLOSE_S + 1) for p in opened),
                             return_exceptions=True)  # fmt: skip


__all__ = ["Publisher", "parse_publish", "publishing"]
