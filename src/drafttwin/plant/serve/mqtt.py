"""``drafttwin plant serve --mqtt``: live plants published to an MQTT broker (paho-mqtt), and
the embedded broker (amqtt) started when none answers.

Topics, per machine ``NAME`` (docs/twin.md, "The plant's MQTT payload"):

* ``drafttwin/NAME/sample``: one JSON object per sample, schema
  ``schemas/sample.schema.json`` (shipped with the package): ``v``, ``seq``, ``time`` (epoch
  s), ``timestamp`` (ISO 8601 UTC), ``front`` ... ``back``, ``motor`` (r/min, ``null`` when
  dropped), ``supply_hz`` (Hz), ``units``, ``lag_s``. QoS 0 by default, 1 with ``qos=1``.
* ``drafttwin/NAME/status``: ``online`` / ``offline``, retained, QoS 1; ``offline`` is also
  the connection's will message, so a subscriber learns of a publisher that died.
* ``drafttwin/NAME/setpoint``: a new VFD set-point for the live plant, a JSON number (Hz).
* ``drafttwin/NAME/identification``: who the machine is (serial number, product instance
  URI, manufacturer, model: :mod:`drafttwin.wire.identity`), retained, QoS 1; schema
  ``schemas/identification.schema.json``.
* with ``--sliver``: ``drafttwin/NAME/sliver`` (a batch of the sliver sensors' readings,
  ``schemas/sliver.schema.json``) and ``drafttwin/NAME/leveller`` (retained: the leveller's
  setting, the fibres, the sensors; ``schemas/leveller.schema.json``); :mod:`.sliver`.

Each machine has its own connection (a will message belongs to a connection).

amqtt (pure Python, MQTT 3.1.1) is the embedded broker for tests and a single machine; it
managed about 2.7k messages/s on the test machine (docs/twin.md). For a hall use Mosquitto.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import shutil
import socket
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drafttwin._constants import __version__
from drafttwin.errors import ConfigError
from drafttwin.plant.faults import FaultSpec
from drafttwin.plant.live import LivePlant
from drafttwin.plant.serve.channels import as_published, plant_channels, values_of
from drafttwin.plant.serve.closing import say_offline_and_close
from drafttwin.plant.serve.feed import AHEAD_S, Feed
from drafttwin.plant.serve.pacing import Pacing, catch_up
from drafttwin.wire.conventions import (
    OFFLINE,
    ONLINE,
    Channel,
    parse_hostport,
    sample_payload,
    setpoint_topic,
    status_topic,
    topic,
)
from drafttwin.wire.identity import identification_payload, plant_identity

SCHEMA = Path(__file__).with_name("schemas") / "sample.schema.json"
"""JSON Schema of the sample payload."""


# ---- broker ---------------------------------------------------------------------------------
def broker_answers(host: str, port: int) -> bool:
    with contextlib.suppress(OSError), socket.create_connection((host, port), timeout=0.5):
        return True
    return False


async def start_broker(host: str, port: int, users: dict[str, str] | None = None,
                       cert_dir: Path | None = None) -> Any:  # fmt: skip
    """An embedded amqtt broker on ``host:port`` (no $SYS topics); ``shutdown()`` it when
    done. With ``users`` (name -> password) only they may connect (argon2-hashed password file
    in a private temporary folder, removed once the broker has read it), else anyone on the
    address."""
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
    try:
        broker = Broker(config)
        await broker.start()
    finally:  # the plugin has read the hashes: no password file left behind in /tmp
        if users:
            shutil.rmtree(folder, ignore_errors=True)
    return broker


async def _broker_for(host: str, port: int, mode: str, username: str | None,
                      password: str | None, cert_dir: Path | None) -> Any:  # fmt: skip
    """The embedded broker when one is to be started (else ``None``), after checking ``mode``."""
    answers = broker_answers(host, port)
    if mode == "external" and not answers:
        raise ConfigError(f"no MQTT broker answers at {host}:{port}", where="--mqtt",
                          fix="start the broker first (e.g. mosquitto -p PORT), or drop "
                          "--broker external to start the embedded one")  # fmt: skip
    if mode == "embedded" and answers:
        raise ConfigError(f"{host}:{port} is taken (a broker or another server answers)",
                          where="--mqtt", fix="choose a free port for the embedded broker, or "
                          "use --broker external to publish to the one there")  # fmt: skip
    if answers:
        return None
    if host not in ("127.0.0.1", "localhost"):
        raise ConfigError(f"no MQTT broker answers at {host}:{port}", where="--mqtt",
                          fix="start one there, or use 127.0.0.1 to start the embedded one")  # fmt: skip
    users = None if username is None else {username: password or ""}
    return await start_broker(host, port, users, cert_dir)


# ---- the live plant as a publisher ----------------------------------------------------------
@dataclass
class _Publisher:
    """One machine: its plant, its connection (with its will) and a pending set-point."""

    name: str
    plant: LivePlant
    channels: tuple[Channel, ...]
    client: Any = None
    pending: float | None = None
    sliver: Any = None  # its LiveSliver (plant serve --sliver)


async def _connect(p: _Publisher, host: str, port: int, qos: int, username: str | None,
                   password: str | None, cert_dir: Path | None) -> None:  # fmt: skip
    import paho.mqtt.client as mqtt

    def on_message(client: Any, userdata: Any, msg: Any) -> None:
        with contextlib.suppress(ValueError, TypeError):
            value = float(json.loads(msg.payload))
            if math.isfinite(value):
                p.pending = value

    announced: list[Any] = []  # the online and identification messages (QoS 1)

    def on_connect(client: Any, *_: Any) -> None:  # also after a reconnect
        client.subscribe(setpoint_topic(p.name), qos=1)
        who = identification_payload(plant_identity(p.plant.machine.seed or 0), __version__)
        announced[:] = [client.publish(status_topic(p.name), ONLINE, qos=1, retain=True),
                        client.publish(topic(p.name, "identification"), json.dumps(who), qos=1,
                                       retain=True)]  # fmt: skip
        if p.sliver is not None:
            from drafttwin.plant.serve.sliver import announce_leveller

            announced.append(announce_leveller(client, p.name, p.sliver))

    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv311)
    client.on_message, client.on_connect = on_message, on_connect
    client.max_queued_messages_set(100_000)  # a stalled broker must not grow memory forever
    client.will_set(status_topic(p.name), OFFLINE, qos=1, retain=True)
    if username is not None:
        client.username_pw_set(username, password)
    if cert_dir is not None:
        client.tls_set(ca_certs=str(cert_dir / "mqtt_cert.pem"))
    p.client = client
    await asyncio.to_thread(client.connect, host, port, 30)
    client.loop_start()
    for _ in range(100):  # a TCP listener that is no MQTT broker never acknowledges
        # connected, and the broker holds 'online' and who it is (retained) for any subscriber
        if announced and all(m.is_published() for m in announced):
            return
        await asyncio.sleep(0.05)
    raise ConfigError(f"{host}:{port} accepts connections but no MQTT broker answers there",
                      where="--mqtt", fix="give the address of an MQTT broker, or a free "
                      "local port to start the embedded one")  # fmt: skip


async def serve_mqtt(address: str, names: list[str], *, seed: int = 0, rate_hz: float = 100.0,
                     physics: str = "full", ramp_hz_per_s: float = 10.0,
                     duration_s: float | None = None, ready: Any = None,
                     username: str | None = None, password: str | None = None,
                     cert_dir: Path | None = None, broker_mode: str = "auto",
                     on_sample: Any = None, faults: Sequence[FaultSpec] = (),
                     qos: int = 0, pacing: Pacing | None = None,
                     ahead_s: float = AHEAD_S, sliver: Any = None,
                     on_sliver: Callable[[Any, Any], None] | None = None) -> dict[str, int]:  # fmt: skip
    """Publish ``names`` live plants to the broker at ``address``; set-points arrive on
    ``drafttwin/NAME/setpoint``. ``broker_mode``: ``auto`` starts the embedded broker when none
    answers on a local address, ``external`` never starts one (a broker must answer),
    ``embedded`` always starts one (the port must be free). ``qos``: 0 (default) or 1 for the
    samples. ``on_sample(name, sample)`` is called after each publish (the plant's own log).
    ``ahead_s``: how far ahead the physics is computed, as for
    :func:`~drafttwin.plant.serve.opcua.serve_opcua`. ``sliver``
    (:class:`~drafttwin.plant.sliver_channel.SliverSettings`) makes each machine's sliver and
    publishes its sensors; ``on_sliver(live_sliver, batch)`` after each batch."""
    if qos not in (0, 1):
        raise ConfigError(f"QoS {qos}", where="--qos", fix="use 0 or 1")
    host, port = parse_hostport(address, "--mqtt")
    broker = await _broker_for(host, port, broker_mode, username, password, cert_dir)
    publishers = []
    for k, n in enumerate(names):
        plant = LivePlant(seed + k, rate_hz, physics=physics, ramp_hz_per_s=ramp_hz_per_s,
                          faults=faults)  # fmt: skip
        pub = _Publisher(n, plant, plant_channels(plant))
        if sliver is not None:  # before the feed's worker computes ahead
            from drafttwin.plant.live_sliver import LiveSliver

            pub.sliver = LiveSliver(plant, sliver, seed + k, n)
        publishers.append(pub)
    try:
        for p in publishers:
            await _connect(p, host, port, qos, username, password, cert_dir)
        if ready is not None:
            ready(f"MQTT {host}:{port}" + (" (embedded amqtt broker)" if broker else
                                           " (external broker)"))  # fmt: skip
        pacing = pacing if pacing is not None else Pacing(rate_hz)
        with Feed([p.plant for p in publishers], rate_hz, ahead_s=ahead_s) as feed:
            return await _publish(publishers, pacing, feed, qos, duration_s, on_sample,
                                  on_sliver)  # fmt: skip
    finally:
        await say_offline_and_close([(p.name, p.client) for p in publishers])
        if broker is not None:
            await broker.shutdown()


async def _publish(publishers: list[_Publisher], pacing: Pacing, feed: Feed, qos: int,
                   duration_s: float | None, on_sample: Callable[[str, Any], None] | None,
                   on_sliver: Callable[[Any, Any], None] | None = None) -> dict[str, int]:  # fmt: skip
    t0 = pacing.start()
    for p in publishers:
        p.plant.t0_s = t0
    end = None if duration_s is None else round(duration_s * pacing.rate_hz)
    pacing.end_tick = feed.end = end
    while end is None or pacing.tick < end:
        skip = await pacing.next_tick()
        await catch_up([p.plant for p in publishers], skip, pacing.rate_hz)
        t_s = 0.0
        for p in publishers:
            if p.pending is not None:
                with contextlib.suppress(ConfigError):
                    p.plant.set_supply(p.pending)
                p.pending = None
            s = as_published(p.plant.step(), p.channels)
            t_s = s.time_s
            payload = sample_payload(s.seq, s.time_s, values_of(s), p.channels,
                                     lag_s=pacing.now_s() - s.time_s)  # fmt: skip
            p.client.publish(topic(p.name, "sample"), json.dumps(payload), qos=qos)
            if on_sample is not None:
                on_sample(p.name, s)
            batch = None if p.sliver is None else p.sliver.after()
            if batch is not None:
                from drafttwin.plant.serve.sliver import publish_sliver_mqtt

                publish_sliver_mqtt(p.client, batch, qos)
                if on_sliver is not None:
                    on_sliver(p.sliver, batch)
        feed.took()
        pacing.published(t_s)
    return {p.name: p.plant.seq for p in publishers}


__all__ = ["SCHEMA", "broker_answers", "parse_hostport", "serve_mqtt", "setpoint_topic",
           "start_broker", "status_topic"]  # fmt: skip
