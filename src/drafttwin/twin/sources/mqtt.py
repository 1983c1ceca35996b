"""MQTT: the twin's source (paho-mqtt). The plant's publisher and the embedded broker are in
:mod:`drafttwin.plant.serve.mqtt`.

Topics, per machine ``NAME`` (a mapping file may name others):

* ``drafttwin/NAME/sample``: one JSON object per sample; the source reads the mapping's
  ``fields`` (``seq``, ``time`` in epoch s, the channels, ``supply_hz``) and ignores the rest
  (``v``, ``timestamp``, ``units``, ``lag_s``: schema ``plant/serve/schemas/sample.schema.json``).
* ``drafttwin/NAME/samples``: ``{"v": 1, "samples": [...]}``, up to :data:`MAX_BATCH` sample
  objects in one message (``plant replay``: records served faster than real time);
* ``drafttwin/NAME/setpoint``: a new VFD set-point for the live plant, a JSON number (Hz).
* ``drafttwin/NAME/identification``: who the machine is (retained; the twin keeps each
  machine's learned baseline with its serial number, :mod:`drafttwin.wire.identity`).
* ``drafttwin/NAME/sliver`` and ``drafttwin/NAME/leveller`` (retained): the sliver sensors'
  readings in batches and their description (``plant serve --sliver``,
  :mod:`drafttwin.wire.sliver`), subscribed at QoS 1.

Payloads are checked before use: over ``MAX_PAYLOAD`` bytes, not JSON, not an object, a
field missing, of the wrong type, out of range or not finite: dropped and counted. The paho
network thread hands samples to the event loop; past ``MAX_BACKLOG`` waiting samples (a flood
faster than the twin) new ones are dropped and counted, so memory stays bounded.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from drafttwin.twin.sources.base import BACKOFF_S, Emit, Report, Sample, Source
from drafttwin.twin.sources.mapping import MachineMap
from drafttwin.wire.conventions import parse_hostport, setpoint_topic
from drafttwin.wire.sliver import MAX_DESCRIPTION, SliverBatch, parse_sliver

MAX_PAYLOAD = 16_384
"""Largest accepted payload, bytes (a sample is about 150)."""
MAX_BATCH = 200
"""Most samples in one batch payload (``drafttwin/NAME/samples``)."""
MAX_BATCH_PAYLOAD = 131_072
"""Largest accepted batch payload, bytes."""
MAX_BACKLOG = 50_000
"""Samples waiting for the event loop before new ones are dropped."""


class MqttSource(Source):
    """Subscribe to each machine's topic (QoS 0) on a broker; reconnect with backoff.

    With ``share`` (a group name) it subscribes over MQTT 5 to ``$share/GROUP/TOPIC``: the
    broker hands each message to one member of the group (MQTT 5.0 §4.8.2). Which member is
    the broker's choice: Mosquitto 2.0 takes turns per message, so one machine's samples
    spread over the members (docs/twin.md); EMQX's ``hash_topic`` keeps a topic on one."""

    def __init__(self, host: str, port: int, machines: tuple[MachineMap, ...],
                 username: str | None = None, password: str | None = None,
                 ca_file: Path | None = None, *, share: str | None = None) -> None:  # fmt: skip
        self.spec, self.host, self.port, self.machines = (
            f"mqtt://{host}:{port}",
            host,
            port,
            machines,
        )
        self.by_topic = {m.topic: m for m in machines}
        # who each machine is (retained beside its samples: drafttwin/NAME/identification),
        # and its samples in batches (drafttwin/NAME/samples: a replay faster than real time)
        beside = {t.rsplit("/", 1)[0]: m for t, m in self.by_topic.items() if t.endswith("/sample")}
        self.by_ident = {f"{base}/identification": m for base, m in beside.items()}
        self.by_batch = {f"{base}/samples": m for base, m in beside.items()}
        self.by_sliver = {f"{base}/sliver": m for base, m in beside.items()}
        self.by_leveller = {f"{base}/leveller": m for base, m in beside.items()}
        self.username, self.password = username, password
        self.ca_file = ca_file  # TLS, trusting exactly this certificate
        self.share = share
        self.refused: str | None = None  # why the broker would not do what was asked
        if share is not None:
            self.spec += f"?share={share}"
        self.queued = 0  # written by the network thread only
        self.handled = 0  # written by the event loop only

    def bind(self, loop: asyncio.AbstractEventLoop, emit: Emit, report: Report) -> None:
        """Hand samples to ``emit`` / drops to ``report`` on ``loop`` (from the network thread)."""
        self._loop, self._emit, self._report = loop, emit, report
        self.flooded: dict[str, int] = {}  # dropped in the network thread, per machine
        self._flood_reported: dict[str, int] = {}

    def _deliver(self, item: Sample | SliverBatch | tuple[str, str]) -> None:
        self.handled += 1
        if isinstance(item, Sample | SliverBatch):
            self._emit(item)
        else:
            self._report(item[0], "dropped", item[1])
        for name, n in list(self.flooded.items()):  # drops of a flood, counted here at once
            new = n - self._flood_reported.get(name, 0)
            if new:
                self._report(name, "dropped", f"flood: {new} samples over the backlog limit", new)
                self._flood_reported[name] = n

    def _identified(self, machine: str, payload: bytes) -> None:
        """The retained identification (checked: a malformed one is counted as dropped)."""
        from drafttwin.wire.identity import MachineIdentity

        try:
            identity = MachineIdentity.from_dict(json.loads(payload))
        except (ValueError, RecursionError):
            identity = None
        if identity is None:
            self._report(machine, "dropped", "identification payload malformed")
        else:
            self._report(machine, "identity", json.dumps(identity.to_dict()))

    def _subscribe(self, client: Any, userdata: Any, flags: Any, reason: Any,
                   properties: Any = None) -> None:  # fmt: skip
        available = getattr(properties, "SharedSubscriptionAvailable", 1)  # CONNACK, MQTT 5
        if self.share is not None and available == 0:
            self.refused = "the broker has no shared subscriptions"
            client.disconnect()
            return
        prefix = "" if self.share is None else f"$share/{self.share}/"
        for topic in (*self.by_topic, *self.by_batch):
            client.subscribe(prefix + topic, qos=0)
        for topic in self.by_sliver:  # batches of sliver readings: at least once
            client.subscribe(prefix + topic, qos=1)
        for topic in (*self.by_ident, *self.by_leveller):  # retained: every member gets it
            client.subscribe(topic, qos=1)

    def on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        """paho's callback (network thread): check, then queue for the loop, or count a drop."""
        m = self.by_topic.get(msg.topic)
        if m is None:
            batch = self.by_batch.get(msg.topic)
            if batch is not None:
                self._queue(batch, _parse_batch(batch, msg.payload))
                return
            sliver = self.by_sliver.get(msg.topic)
            if sliver is not None:
                got = parse_sliver(sliver.name, msg.payload)
                self._queue(sliver, [got if isinstance(got, SliverBatch) else (sliver.name, got)])
                return
            lev = self.by_leveller.get(msg.topic)
            if lev is not None:
                text = (msg.payload[: MAX_DESCRIPTION + 1]).decode("utf-8", errors="replace")
                self._loop.call_soon_threadsafe(self._report, lev.name, "leveller", text)
                return
            who = self.by_ident.get(msg.topic)
            if who is not None and len(msg.payload) <= MAX_PAYLOAD:
                self._loop.call_soon_threadsafe(self._identified, who.name, msg.payload)
            return
        self._queue(m, [_parse(m, msg.payload)])

    def _queue(
        self, m: MachineMap, items: Sequence[Sample | SliverBatch | tuple[str, str]]
    ) -> None:
        """Hand parsed samples (or drops) to the loop; past the backlog, count them dropped."""
        if self.queued - self.handled + len(items) > MAX_BACKLOG:
            self.flooded[m.name] = self.flooded.get(m.name, 0) + len(items)  # memory flat
            return
        self.queued += len(items)
        for item in items:
            self._loop.call_soon_threadsafe(self._deliver, item)

    async def run(self, emit: Emit, report: Report) -> None:
        import paho.mqtt.client as mqtt

        loop = asyncio.get_running_loop()
        self.bind(loop, emit, report)
        lost = asyncio.Event()

        def on_disconnect(*_: Any) -> None:
            loop.call_soon_threadsafe(lost.set)

        attempt = 0
        self.refused = None
        protocol = mqtt.MQTTv311 if self.share is None else mqtt.MQTTv5  # $share is MQTT 5
        while True:
            client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, protocol=protocol)
            client.on_message = self.on_message
            client.on_disconnect = on_disconnect
            client.on_connect = self._subscribe  # on every (re)connect, once acknowledged
            if self.username is not None:
                client.username_pw_set(self.username, self.password)
            if self.ca_file is not None:
                client.tls_set(ca_certs=str(self.ca_file))
            lost.clear()
            try:
                await asyncio.to_thread(client.connect, self.host, self.port, 30)
                client.loop_start()
                for _ in range(100):  # live once the broker acknowledged, else reconnect
                    if client.is_connected():
                        break
                    await asyncio.sleep(0.05)
                else:
                    raise OSError("no MQTT acknowledgement from the broker" + (
                        " (share= needs MQTT 5, e.g. Mosquitto; the embedded amqtt speaks "
                        "3.1.1 only)" if self.share else ""))  # fmt: skip
                self._set("live", report)
                attempt = 0
                await lost.wait()
                self._set("reconnecting", report, self.refused or "broker connection lost")
            except asyncio.CancelledError:
                raise
            except OSError as exc:
                self._set("reconnecting", report, f"{type(exc).__name__}: {exc}"[:200])
            finally:
                with contextlib.suppress(Exception):
                    client.disconnect()
                    client.loop_stop()
            await asyncio.sleep(BACKOFF_S[min(attempt, len(BACKOFF_S) - 1)])
            attempt += 1


def _parse_batch(m: MachineMap, payload: bytes) -> list[Sample | tuple[str, str]]:
    """A batch payload ``{"v": 1, "samples": [SAMPLE, ...]}`` (schema
    ``plant/serve/schemas/samples.schema.json``): each sample checked as a single one."""
    if len(payload) > MAX_BATCH_PAYLOAD:
        return [(m.name, f"batch payload of {len(payload)} bytes (limit {MAX_BATCH_PAYLOAD})")]
    try:
        obj = json.loads(payload)
    except (ValueError, RecursionError):
        return [(m.name, "batch payload is not JSON")]
    samples = obj.get("samples") if isinstance(obj, dict) else None
    if not isinstance(samples, list) or not 0 < len(samples) <= MAX_BATCH:
        return [(m.name, f"batch payload without a list of 1-{MAX_BATCH} samples")]
    out: list[Sample | tuple[str, str]] = []
    for one in samples:
        row = m.from_json(one)
        out.append((m.name, "batch sample fields missing, of the wrong type or out of range")
                   if row is None else Sample(m.name, *row))  # fmt: skip
    return out


def _parse(m: MachineMap, payload: bytes) -> Sample | tuple[str, str]:
    if len(payload) > MAX_PAYLOAD:
        return (m.name, f"payload of {len(payload)} bytes (limit {MAX_PAYLOAD})")
    try:
        obj = json.loads(payload)
    except (ValueError, RecursionError):
        return (m.name, "payload is not JSON")
    row = m.from_json(obj)
    if row is None:
        return (m.name, "payload fields missing, of the wrong type or out of range")
    return Sample(m.name, *row)


__all__ = ["MAX_BACKLOG", "MAX_PAYLOAD", "MqttSource", "parse_hostport", "setpoint_topic"]
