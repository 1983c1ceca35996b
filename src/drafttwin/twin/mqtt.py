"""MQTT: the twin's source (paho-mqtt), the live plant's publisher, an embedded broker (amqtt).

Topics, per machine ``NAME`` (a mapping file may name others):

* ``drafttwin/NAME/sample``: one JSON object per sample keyed by the mapping's ``fields``
  (``{"seq": 12, "time": 1795596978.12, "front": 1814.4, ..., "supply_hz": 48.47}``).
* ``drafttwin/NAME/setpoint``: a new VFD set-point for the live plant, a JSON number (Hz).

Payloads are checked before use: over ``MAX_PAYLOAD`` bytes, not JSON, not an object, a
field missing, of the wrong type, out of range or not finite: dropped and counted. The paho
network thread hands samples to the event loop; past ``MAX_BACKLOG`` waiting samples (a flood
faster than the twin) new ones are dropped and counted, so memory stays bounded.

amqtt (pure Python, MQTT 3.1.1) is the embedded broker for tests and a single machine; it
managed about 2.7k messages/s on the test machine (docs/twin.md). For a hall use Mosquitto.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import socket
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from drafttwin.errors import ConfigError
from drafttwin.plant.faults import FaultSpec
from drafttwin.twin.mapping import MachineMap
from drafttwin.twin.sources import BACKOFF_S, Emit, Report, Sample, Source

MAX_PAYLOAD = 16_384
"""Largest accepted payload, bytes (a sample is about 150)."""
MAX_BACKLOG = 50_000
"""Samples waiting for the event loop before new ones are dropped."""


def parse_hostport(text: str, where: str) -> tuple[str, int]:
    host, _, port = text.removeprefix("mqtt://").rstrip("/").rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ConfigError(f"bad MQTT address {text!r}", where=where,
                          fix="write HOST:PORT, e.g. 127.0.0.1:1883")  # fmt: skip
    return host, int(port)


def setpoint_topic(machine: str) -> str:
    return f"drafttwin/{machine}/setpoint"


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

    def _deliver(self, item: Sample | tuple[str, str]) -> None:
        self.handled += 1
        if isinstance(item, Sample):
            self._emit(item)
        else:
            self._report(item[0], "dropped", item[1])
        for name, n in list(self.flooded.items()):  # drops of a flood, counted here at once
            new = n - self._flood_reported.get(name, 0)
            if new:
                self._report(name, "dropped", f"flood: {new} samples over the backlog limit", new)
                self._flood_reported[name] = n

    def _subscribe(self, client: Any, userdata: Any, flags: Any, reason: Any,
                   properties: Any = None) -> None:  # fmt: skip
        available = getattr(properties, "SharedSubscriptionAvailable", 1)  # CONNACK, MQTT 5
        if self.share is not None and available == 0:
            self.refused = "the broker has no shared subscriptions"
            client.disconnect()
            return
        prefix = "" if self.share is None else f"$share/{self.share}/"
        for topic in self.by_topic:
            client.subscribe(prefix + topic, qos=0)

    def on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        """paho's callback (network thread): check, then queue for the loop, or count a drop."""
        m = self.by_topic.get(msg.topic)
        if m is None:
            return
        if self.queued - self.handled >= MAX_BACKLOG:
            self.flooded[m.name] = self.flooded.get(m.name, 0) + 1  # no callback: memory flat
            return
        self.queued += 1
        self._loop.call_soon_threadsafe(self._deliver, _parse(m, msg.payload))

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


# ---- broker ---------------------------------------------------------------------------------
def broker_answers(host: str, port: int) -> bool:
    with contextlib.suppress(OSError), socket.create_connection((host, port), timeout=0.5):
        return True
    return False


async def start_broker(host: str, port: int, users: dict[str, str] | None = None,
                       cert_dir: Path | None = None) -> Any:  # fmt: skip
    """An embedded amqtt broker on ``host:port`` (no $SYS topics); ``shutdown()`` it when
    done. With ``users`` (name -> password) only they may connect (argon2-hashed password file
    in a private temporary folder), else anyone on the address."""
    import tempfile

    from amqtt.broker import Broker

    auth: dict[str, Any] = {
        "amqtt.plugins.authentication.AnonymousAuthPlugin": {"allow_anonymous": True}
    }
    if users:
        from pwdlib import PasswordHash
        from pwdlib.hashers.argon2 import Argon2Hasher

        hasher = PasswordHash((Argon2Hasher(),))
        folder = Path(tempfile.mkdtemp(prefix="drafttwin-mqtt-"))  # mode 0700
        path = folder / "passwords"
        path.write_text(
            "".join(f"{u}:{hasher.hash(p)}\n" for u, p in users.items()), encoding="utf-8"
        )
        auth = {"amqtt.plugins.authentication.FileAuthPlugin": {"password_file": str(path)}}
    listener: dict[str, Any] = {"type": "tcp", "bind": f"{host}:{port}"}
    if cert_dir is not None:  # TLS with the certificate 'drafttwin twin certs' made
        listener.update(ssl=True, certfile=str(cert_dir / "mqtt_cert.pem"),
                        keyfile=str(cert_dir / "mqtt_key.pem"))  # fmt: skip
    config = {"listeners": {"default": listener}, "plugins": auth}
    broker = Broker(config)
    await broker.start()
    return broker


# ---- the live plant as a publisher ----------------------------------------------------------
async def serve_mqtt(address: str, names: list[str], *, seed: int = 0, rate_hz: float = 100.0,
                     physics: str = "full", ramp_hz_per_s: float = 10.0,
                     duration_s: float | None = None, ready: Any = None,
                     username: str | None = None, password: str | None = None,
                     cert_dir: Path | None = None, broker_mode: str = "auto",
                     on_sample: Any = None,
                     faults: Sequence[FaultSpec] = ()) -> dict[str, int]:  # fmt: skip
    """Publish ``names`` live plants to the broker at ``address``; set-points arrive on
    ``drafttwin/NAME/setpoint``. ``broker_mode``: ``auto`` starts the embedded broker when none
    answers on a local address, ``external`` never starts one (a broker must answer),
    ``embedded`` always starts one (the port must be free). ``on_sample(name, sample)`` is
    called after each publish (the plant's own log)."""
    import paho.mqtt.client as mqtt

    from drafttwin.plant.live import LivePlant

    host, port = parse_hostport(address, "--mqtt")
    broker = None
    answers = broker_answers(host, port)
    if broker_mode == "external" and not answers:
        raise ConfigError(f"no MQTT broker answers at {host}:{port}", where="--mqtt",
                          fix="start the broker first (e.g. mosquitto -p PORT), or drop "
                          "--broker external to start the embedded one")  # fmt: skip
    if broker_mode == "embedded" and answers:
        raise ConfigError(f"{host}:{port} is taken (a broker or another server answers)",
                          where="--mqtt", fix="choose a free port for the embedded broker, or "
                          "use --broker external to publish to the one there")  # fmt: skip
    if not answers:
        if host not in ("127.0.0.1", "localhost"):
            raise ConfigError(f"no MQTT broker answers at {host}:{port}", where="--mqtt",
                              fix="start one there, or use 127.0.0.1 to start the embedded one")  # fmt: skip
        users = None if username is None else {username: password or ""}
        broker = await start_broker(host, port, users, cert_dir)
    plants = {n: LivePlant(seed + k, rate_hz, physics=physics, ramp_hz_per_s=ramp_hz_per_s,
                           faults=faults)
              for k, n in enumerate(names)}  # fmt: skip
    pending: dict[str, float] = {}

    def on_message(client: Any, userdata: Any, msg: Any) -> None:
        name = msg.topic.split("/")[1] if msg.topic.count("/") == 2 else ""
        with contextlib.suppress(ValueError, TypeError):
            value = float(json.loads(msg.payload))
            if name in plants and math.isfinite(value):
                pending[name] = value

    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv311)
    client.on_message = on_message
    client.max_queued_messages_set(100_000)  # a stalled broker must not grow memory forever
    if username is not None:
        client.username_pw_set(username, password)
    if cert_dir is not None:
        client.tls_set(ca_certs=str(cert_dir / "mqtt_cert.pem"))
    await asyncio.to_thread(client.connect, host, port, 30)
    client.loop_start()
    for _ in range(100):  # a TCP listener that is no MQTT broker never acknowledges
        if client.is_connected():
            break
        await asyncio.sleep(0.05)
    else:
        client.loop_stop()
        if broker is not None:
            await broker.shutdown()
        raise ConfigError(f"{host}:{port} accepts connections but no MQTT broker answers there",
                          where="--mqtt", fix="give the address of an MQTT broker, or a free "
                          "local port to start the embedded one")  # fmt: skip
    for n in names:
        client.subscribe(setpoint_topic(n), qos=1)
    if ready is not None:
        ready(f"MQTT {host}:{port}" + (" (embedded amqtt broker)" if broker else
                                       " (external broker)"))  # fmt: skip
    try:
        return await _publish(client, plants, pending, rate_hz, duration_s, on_sample)
    finally:
        client.loop_stop()
        client.disconnect()
        if broker is not None:
            await broker.shutdown()


async def _publish(client: Any, plants: dict, pending: dict[str, float], rate_hz: float,
                   duration_s: float | None, on_sample: Any = None) -> dict[str, int]:  # fmt: skip
    t0 = time.time()
    for p in plants.values():
        p.t0_s = t0
    start = time.monotonic()
    end = math.inf if duration_s is None else duration_s * rate_hz
    k = 0
    while k < end:
        k += 1
        delay = start + k / rate_hz - time.monotonic()
        # always yield: a loop behind schedule must still let the others run
        await asyncio.sleep(max(delay, 0.0))
        for name, plant in plants.items():
            if name in pending:
                with contextlib.suppress(ConfigError):
                    plant.set_supply(pending.pop(name))
            s = plant.step()
            payload = {"seq": s.seq, "time": s.time_s, "motor": _num(s.motor_rpm),
                       "supply_hz": s.supply_hz,
                       **{c: _num(v) for c, v in zip(("front", "second", "third", "back"),
                                                     s.rollers_rpm, strict=True)}}  # fmt: skip
            client.publish(f"drafttwin/{name}/sample", json.dumps(payload), qos=0)
            if on_sample is not None:
                on_sample(name, s)
    return {n: p.seq for n, p in plants.items()}


def _num(x: float) -> float | None:
    """A dropped sample is ``null`` in JSON (read back as missing)."""
    return float(x) if math.isfinite(x) else None


__all__ = ["MqttSource", "broker_answers", "parse_hostport", "serve_mqtt", "start_broker"]
