"""'plant serve' as plant software reads it: the wall clock kept (or the lateness said), OPC UA
analog items with UNECE units, ranges, the server's identity and Machinery-style
identification, one source time per sample in every node; MQTT payloads valid against the
shipped JSON Schema, a retained status and the will message when the plant is killed."""

from __future__ import annotations

import asyncio
import datetime as dt
import json
import signal
import subprocess
import threading
import time
from typing import Any

import numpy as np
import pytest

from drafttwin.plant.live import LivePlant
from drafttwin.plant.serve.mqtt import SCHEMA, serve_mqtt
from drafttwin.plant.serve.opcua import serve_opcua
from drafttwin.plant.serve.pacing import Pacing
from drafttwin.wire.conventions import RPM, UNECE_NAMESPACE, iso_time

from ._twin import cli, env, free_port

pytestmark = pytest.mark.timeout(120)


def test_a_late_loop_says_so_and_skips_to_the_wall_clock() -> None:
    """Blocked 0.35 s at a 100 Hz tick with max_lag 0.2 s: it skips ~35 samples, the lag it
    reports is the block, and one warning (rate-limited) is said, not one per tick."""
    said: list[str] = []
    pacing = Pacing(100.0, max_lag_s=0.2, warn_lag_s=0.05, warn=said.append)
    pacing.start()

    async def run() -> list[int]:
        skips = []
        for k in range(6):
            skips.append(await pacing.next_tick())
            if k == 2:
                time.sleep(0.35)  # a busy machine: the loop is held
            pacing.published(pacing.t0_s + pacing.tick / pacing.rate_hz)
        return skips

    skips = asyncio.run(run())
    assert skips[:3] == [0, 0, 0] and sum(skips) == skips[3]
    assert 30 <= skips[3] <= 45, skips  # 0.35 s at 100 Hz, less the tick it was on
    assert pacing.skipped == skips[3]
    assert 0.3 <= pacing.max_seen_lag_s < 0.5
    assert pacing.warnings == 1 and len(said) == 1 and "behind the wall clock" in said[0]
    assert "samples skipped" in pacing.summary()


def test_by_default_a_late_loop_publishes_every_sample_and_warns() -> None:
    said: list[str] = []
    pacing = Pacing(100.0, warn_lag_s=0.05, warn=said.append)
    pacing.start()

    async def run() -> list[int]:
        skips = []
        for k in range(4):
            skips.append(await pacing.next_tick())
            if k == 1:
                time.sleep(0.2)
            pacing.published(pacing.t0_s + pacing.tick / pacing.rate_hz)
        return skips

    assert asyncio.run(run()) == [0, 0, 0, 0] and pacing.skipped == 0
    assert pacing.max_seen_lag_s >= 0.15 and pacing.late_ticks >= 1
    assert len(said) == 1 and "every sample is still published" in said[0]


def test_a_skipped_span_is_the_same_physics_as_stepping_through_it() -> None:
    """skip(n) integrates the missed span in one call: the next sample's true speeds equal
    those of a plant stepped sample by sample, and its counter jumps by n."""
    a, b = LivePlant(3, 100.0, physics="reduced"), LivePlant(3, 100.0, physics="reduced")
    a.set_supply(40.0)
    b.set_supply(40.0)
    for _ in range(49):
        a.step()
    b.skip(49)
    sa, sb = a.step(), b.step()
    assert sb.seq == sa.seq == 50 and sb.time_s == sa.time_s
    np.testing.assert_allclose(sb.true_rpm, sa.true_rpm, rtol=2e-3)
    assert b.supply_hz == pytest.approx(a.supply_hz, abs=1e-9)
    finite = np.isfinite(sb.rollers_rpm)  # the encoders measured one window, not the span
    np.testing.assert_allclose(sb.rollers_rpm[finite], sb.true_rpm[finite], rtol=0.01)


async def _opcua_facts(url: str) -> dict[str, Any]:
    from asyncua import Client, ua

    async with Client(url) as client:
        node = client.get_node
        front = node("ns=2;s=fa320a.front_rpm")
        sample = node("ns=2;s=fa320a.sample")
        dv_front, dv_sample = await client.read_attributes([front, sample])
        return {
            "product": await node(ua.ObjectIds.Server_ServerStatus_BuildInfo_ProductName).read_value(),
            "manufacturer": await node(ua.ObjectIds.Server_ServerStatus_BuildInfo_ManufacturerName).read_value(),
            "server_uri": (await node(ua.ObjectIds.Server_ServerArray).read_value())[0],
            "type": (await front.read_type_definition()).Identifier,
            "eu": await node("ns=2;s=fa320a.front_rpm.EngineeringUnits").read_value(),
            "range": await node("ns=2;s=fa320a.front_rpm.EURange").read_value(),
            "description": (await front.read_description()).Text,
            "dims": await sample.read_array_dimensions(),
            "fields": await node("ns=2;s=fa320a.sample.FieldNames").read_value(),
            "serial": await node("ns=2;s=fa320a.Identification.SerialNumber").read_value(),
            "state": (await node("ns=2;s=fa320a.MachineryItemState.CurrentState").read_value()).Text,
            "front": dv_front, "sample": dv_sample,
            "values": [await node(f"ns=2;s=fa320a.{s}").read_value()
                       for s in ("front_rpm", "second_rpm", "motor_rpm", "supply_hz")],
        }  # fmt: skip


def test_opcua_nodes_carry_units_ranges_identity_and_the_source_time() -> None:
    url = f"opc.tcp://127.0.0.1:{free_port()}"

    async def run() -> dict[str, Any]:
        up = asyncio.Event()
        server = asyncio.create_task(serve_opcua(url, ["fa320a"], physics="reduced",
                                                 duration_s=30, ready=up.set))  # fmt: skip
        await asyncio.wait_for(up.wait(), 60)
        await asyncio.sleep(0.3)
        try:
            return await _opcua_facts(url)
        finally:
            server.cancel()
            with pytest.raises(asyncio.CancelledError):
                await server

    f = asyncio.run(run())
    assert (f["product"], f["manufacturer"]) == ("drafttwin plant", "drafttwin")
    assert f["server_uri"] == "urn:drafttwin:plant:server"
    assert f["type"] == 2368  # AnalogItemType
    assert (f["eu"].NamespaceUri, f["eu"].UnitId) == (UNECE_NAMESPACE, RPM.unit_id) == (
        UNECE_NAMESPACE, 0x52504D)  # fmt: skip
    assert f["range"].Low == 0 and f["range"].High > f["values"][0] > 1000
    assert f["description"] != "front_rpm" and "roller" in f["description"]
    assert f["dims"] == [8] and f["fields"][:3] == ["seq", "time", "front"]
    assert f["serial"] == "FA320A-SIM-0" and f["state"] == "Executing"
    for v in f["values"]:  # as measured: no binary noise from the unit conversion
        assert v == round(v, 2) and repr(v) == repr(round(v, 2))
    # one clock: the sample's SourceTimestamp is its own time, and the scalar's lies on the
    # same sample grid (a sample's time, not the instant the server wrote it)
    row = f["sample"].Value.Value
    t_row, seq = row[1], row[0]
    assert f["sample"].SourceTimestamp == dt.datetime.fromtimestamp(t_row, tz=dt.UTC)
    t0 = t_row - seq / 100.0
    t_front = f["front"].SourceTimestamp.timestamp()
    k = (t_front - t0) * 100.0
    assert abs(k - round(k)) < 1e-3 and 0 < round(k) <= seq + 2, (k, seq)


def _subscriber(port: int, topics: list[str]) -> tuple[Any, list[tuple[str, bytes, bool]]]:
    import paho.mqtt.client as mqtt

    got: list[tuple[str, bytes, bool]] = []
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
    client.on_message = lambda c, u, m: got.append((m.topic, m.payload, bool(m.retain)))
    client.on_connect = lambda c, *_: [c.subscribe(t, qos=1) for t in topics]
    client.connect("127.0.0.1", port, 30)
    client.loop_start()
    return client, got


def _wait(pred: Any, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not pred():
        assert time.monotonic() < deadline, what
        time.sleep(0.05)


def _check_payloads(samples: list[bytes]) -> None:
    jsonschema = pytest.importorskip("jsonschema")
    schema = json.loads(SCHEMA.read_text(encoding="utf-8"))
    jsonschema.Draft202012Validator.check_schema(schema)
    validator = jsonschema.Draft202012Validator(schema)
    objs = [json.loads(p) for p in samples]
    for obj in objs:
        validator.validate(obj)
        assert obj["timestamp"] == iso_time(obj["time"])
    seqs = [o["seq"] for o in objs]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    with pytest.raises(jsonschema.ValidationError):  # the schema is strict: it can fail
        validator.validate({**objs[0], "front": "1813.8"})


def _serve_in_thread(port: int, mode: str, duration_s: float) -> threading.Thread:
    def serve() -> None:
        asyncio.run(serve_mqtt(f"127.0.0.1:{port}", ["m1"], physics="reduced",
                               duration_s=duration_s, broker_mode=mode, qos=1))  # fmt: skip

    thread = threading.Thread(target=serve)
    thread.start()
    return thread


def test_mqtt_payloads_over_the_embedded_broker_follow_the_schema() -> None:
    """Embedded broker, in-process plant at QoS 1: schema-valid payloads, status online."""
    from drafttwin.plant.serve.mqtt import broker_answers

    port = free_port()
    thread = _serve_in_thread(port, "embedded", 1.5)
    try:
        _wait(lambda: broker_answers("127.0.0.1", port), 60, "no embedded broker")
        client, got = _subscriber(port, ["drafttwin/m1/sample", "drafttwin/m1/status"])
        _wait(lambda: sum(t.endswith("sample") for t, _, _ in got) >= 20, 30, "no samples")
        assert ("drafttwin/m1/status", b"online") in [(t, p) for t, p, _ in got]
    finally:
        thread.join(60)
    client.loop_stop()
    client.disconnect()
    _check_payloads([p for t, p, _ in got if t.endswith("sample")])


def test_a_killed_plant_is_announced_offline_by_its_will(mosquitto: int) -> None:
    """Mosquitto. A plant that stops cleanly leaves ``offline`` retained. 'plant serve --qos 1'
    killed with SIGKILL: a late subscriber first reads the retained ``online``; after the kill
    the broker sends the will, ``offline``."""
    _serve_in_thread(mosquitto, "external", 0.5).join(60)
    client, got = _subscriber(mosquitto, ["drafttwin/m1/status"])
    _wait(lambda: got, 10, "no retained status")
    assert got == [("drafttwin/m1/status", b"offline", True)]
    client.loop_stop()
    client.disconnect()
    plant = subprocess.Popen(cli("plant", "serve", "--mqtt", f"127.0.0.1:{mosquitto}",
                                 "--broker", "external", "--physics", "reduced", "--qos", "1"),
                             env=env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                             text=True)  # fmt: skip
    try:
        assert plant.stderr is not None
        line = plant.stderr.readline()
        assert "(external broker)" in line, line + plant.stderr.read()
        client, got = _subscriber(mosquitto, ["drafttwin/fa320a/status", "drafttwin/fa320a/sample"])
        _wait(lambda: any(t.endswith("sample") for t, _, _ in got), 30, "no samples")
        status = [(p, r) for t, p, r in got if t.endswith("status")]
        assert status[0] == (b"online", True)  # retained: a late subscriber learns it
        plant.send_signal(signal.SIGKILL)
        plant.wait(timeout=10)
        _wait(lambda: [p for t, p, _ in got if t.endswith("status")][-1] == b"offline", 10,
              "no will message after SIGKILL")  # fmt: skip
        _check_payloads([p for t, p, _ in got if t.endswith("sample")])
        client.loop_stop()
        client.disconnect()
    finally:
        if plant.poll() is None:
            plant.kill()
            plant.wait(timeout=10)


@pytest.mark.parametrize(("args", "said"), [
    (["--opcua", "opc.tcp://127.0.0.1:4840", "--mqtt-user", "bob"], "--mqtt-user is for MQTT"),
    (["--opcua", "opc.tcp://127.0.0.1:4840", "--qos", "1"], "--qos is for MQTT"),
    (["--mqtt", "127.0.0.1:1883", "--history", "60"], "--history is for OPC UA"),
])  # fmt: skip
def test_an_option_of_the_other_transport_is_refused(args: list[str], said: str) -> None:
    """--mqtt-user with --opcua had run without a word (the server open to anyone)."""
    from typer.testing import CliRunner

    from drafttwin.cli import app

    res = CliRunner().invoke(app, ["plant", "serve", *args, "--duration", "1"])
    assert res.exit_code == 2 and said in res.output, res.output
