"""A live machine over MQTT: 'plant serve --mqtt' starts the embedded amqtt broker and
publishes; the twin subscribes; a set-point published on the machine's topic changes the
plant and the twin follows. Hostile payloads on the same topic are counted and dropped."""

from __future__ import annotations

import asyncio
import json
import subprocess
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drafttwin.twin.aio import run_bounded
from drafttwin.twin.build import build_service

from ._twin import cli, env, free_port

pytestmark = pytest.mark.timeout(150)

HOSTILE = [
    b"not json",
    b"[1, 2, 3]",
    b'{"seq": "1", "time": 1.0, "front": 1, "second": 1, "third": 1, "back": 1, "supply_hz": 48}',
    b'{"seq": 1, "time": NaN, "front": 1, "second": 1, "third": 1, "back": 1, "supply_hz": 48}',
    b'{"seq": 1, "time": 1e300, "front": 1, "second": 1, "third": 1, "back": 1, "supply_hz": 48}',
    b'{"seq": 1, "time": 2.0, "front": 1e30, "second": 1, "third": 1, "back": 1, "supply_hz": 48}',
    b'{"seq": 1, "time": 2.0, "front": true, "second": 1, "third": 1, "back": 1, "supply_hz": 48}',
    b'{"seq": 1}',
    b"[" * 100_000 + b"]" * 100_000,  # deep nesting, and over the size limit
    b'{"a": "' + b"x" * 1_000_000 + b'"}',  # 1 MB
]


def _publish(port: int, topic: str, payloads: list[bytes]) -> None:
    import paho.mqtt.client as mqtt

    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
    client.connect("127.0.0.1", port, 30)
    client.loop_start()
    for p in payloads:
        client.publish(topic, p, qos=1).wait_for_publish(10)
    client.loop_stop()
    client.disconnect()


def test_mqtt_machine_setpoint_and_hostile_payloads(
    twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    port = free_port()
    proc = subprocess.Popen(cli("plant", "serve", "--mqtt", f"127.0.0.1:{port}", "--duration",
                                "60", "--ramp", "50"), env=env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline()
        assert "serving fa320a on MQTT" in line, line + proc.stderr.read()
        _, model = twin_files
        service = build_service(model, [f"mqtt://127.0.0.1:{port}"], commit_ms=100)
        seen: list[tuple[float, object]] = []
        service.subscribers.append(
            lambda name, rows, ev: seen.extend((time.monotonic(), r) for r in rows)
        )
        marks: dict[str, float] = {}

        async def drive() -> None:
            while len(seen) < 150:
                await asyncio.sleep(0.05)
            await asyncio.to_thread(_publish, port, "drafttwin/fa320a/sample", HOSTILE * 20)
            marks["before"] = len(seen)
            marks["written"] = time.monotonic()
            await asyncio.to_thread(_publish, port, "drafttwin/fa320a/setpoint", [b"40.0"])
            await asyncio.sleep(2.5)
            service.stop()

        async def main() -> None:
            await asyncio.gather(service.run(duration_s=90), drive())

        asyncio.run(main())
    finally:
        proc.kill()
        proc.wait(timeout=30)
    rows = [r for _, r in seen]
    times = np.array([t for t, _ in seen])
    setpoint = np.array([r.setpoint for r in rows])
    front = np.array([r.measured[0] for r in rows])
    twin = np.array([r.twin[0] for r in rows])
    reached = np.flatnonzero(setpoint == 40.0)
    assert reached.size, "the twin never saw the new set-point"
    assert times[reached[0]] - marks["written"] < 1.0
    before = slice(marks["before"] - 100, marks["before"])
    after = slice(reached[0] + 50, reached[0] + 100)
    assert np.nanmean(front[after]) / np.nanmean(front[before]) == pytest.approx(
        40 / 48.47, rel=0.01
    )
    assert np.nanmean(twin[after]) == pytest.approx(np.nanmean(front[after]), rel=0.01)
    status = service.status()["machines"]["fa320a"]
    assert status["dropped"] == len(HOSTILE) * 20  # every hostile payload counted, none used
    seq = np.array([r.seq for r in rows if r.seq >= 0])
    assert (np.diff(seq) == 1).all()  # the machine's own samples all arrived, in order


def test_a_flood_is_counted_and_dropped_with_flat_memory() -> None:
    """The network thread queues at most MAX_BACKLOG samples for a busy loop; the rest are
    counted, not queued (no callback, no payload kept)."""
    from types import SimpleNamespace

    from drafttwin.twin.service import MachineState, TwinService
    from drafttwin.twin.sources.mapping import MachineMap
    from drafttwin.twin.sources.mqtt import MAX_BACKLOG, MqttSource

    m = MachineMap("df-01", ("front", "second", "third", "back"))
    src = MqttSource("127.0.0.1", 1, (m,))
    emitted: list[object] = []
    service = TwinService({"df-01": MachineState(None, m, "test")}, [src])  # type: ignore[arg-type]
    loop = asyncio.new_event_loop()
    try:
        src.bind(loop, emitted.append, service.report)
        payload = json.dumps({"seq": 1, "time": 1.0, "front": 1.0, "second": 2.0, "third": 3.0,
                              "back": 4.0, "motor": 5.0, "supply_hz": 48.0}).encode()  # fmt: skip
        msg = SimpleNamespace(topic=m.topic, payload=payload)
        flood = MAX_BACKLOG + 30_000
        for _ in range(flood):  # the loop is busy (not running): nothing is handled meanwhile
            src.on_message(None, None, msg)
        assert len(loop._ready) == MAX_BACKLOG  # type: ignore[attr-defined]
        loop.run_until_complete(asyncio.sleep(0))
    finally:
        loop.close()
    assert len(emitted) == MAX_BACKLOG
    assert service.states["df-01"].dropped == 30_000
    assert len(service.states["df-01"].events) <= 32  # one event per 1000 drops, not 30 000


async def _run_together(services: Iterable[Any], duration_s: float) -> None:
    """Several twins side by side on one loop (each its own client), for ``duration_s``."""
    await asyncio.gather(*(s.run(duration_s=duration_s) for s in services))


@pytest.mark.slow  # a broker with argon2 logins and three twins side by side: about 7 s
def test_mqtt_with_a_user_admits_only_that_user(
    twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    _, model = twin_files
    port = free_port()
    secret = {**env(), "DRAFTTWIN_MQTT_PASSWORD": "s3cret-pass-for-the-test",
              "TMPDIR": str(tmp_path)}  # fmt: skip
    proc = subprocess.Popen(cli("plant", "serve", "--mqtt", f"127.0.0.1:{port}", "--mqtt-user",
                                "twin", "--duration", "60", "--physics", "reduced"), env=secret,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline()
        assert "serving fa320a on MQTT" in line, line + proc.stderr.read()
        # the broker has read the password hashes: their file is gone (every run left one)
        assert not list(tmp_path.glob("drafttwin-mqtt-*")), list(tmp_path.iterdir())
        services = {}
        for name, url, password in (("user", f"mqtt://twin@127.0.0.1:{port}", secret["DRAFTTWIN_MQTT_PASSWORD"]),
                                    ("wrong", f"mqtt://twin@127.0.0.1:{port}", "wrong-password"),
                                    ("anonymous", f"mqtt://127.0.0.1:{port}", None)):  # fmt: skip
            with pytest.MonkeyPatch.context() as mp:  # the password is read when it is built
                if password is not None:
                    mp.setenv("DRAFTTWIN_MQTT_PASSWORD", password)
                services[name] = build_service(model, [url])
        run_bounded(_run_together(services.values(), 3.0))
        results = {n: (s.states["fa320a"].received > 50, s.states["fa320a"].state)
                   for n, s in services.items()}  # fmt: skip
    finally:
        proc.kill()
        proc.wait(timeout=30)
    assert results["user"] == (True, "live")
    for refused in ("wrong", "anonymous"):  # still trying (first attempt or a reconnect)
        assert results[refused][0] is False and results[refused][1] in (
            "connecting",
            "reconnecting",
        )


@pytest.mark.slow  # a TLS broker and two twins: about 15 s
def test_mqtt_over_tls_with_the_generated_certificate(
    twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    from drafttwin.wire.certs import make_certificates

    _, model = twin_files
    certs = tmp_path / "certs"
    asyncio.run(make_certificates(certs))
    port = free_port()
    proc = subprocess.Popen(cli("plant", "serve", "--mqtt", f"127.0.0.1:{port}", "--cert", str(certs),
                                "--duration", "60", "--physics", "reduced"), env=env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline()
        assert "serving fa320a on MQTT" in line, line + proc.stderr.read()
        services = {name: build_service(model, [url]) for name, url in (
            ("tls", f"mqtts://127.0.0.1:{port}?cert={certs}"), ("plain", f"mqtt://127.0.0.1:{port}"))}  # fmt: skip
        run_bounded(_run_together(services.values(), 3.0))
        results = {n: s.states["fa320a"].received for n, s in services.items()}
    finally:
        proc.kill()
        proc.wait(timeout=30)
    assert results["tls"] > 50
    assert results["plain"] == 0  # a client without TLS gets nothing from the TLS listener
