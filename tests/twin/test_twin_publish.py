"""The twin publishes its own results (``twin run --publish``): an OPC UA server of its own
(analog items with UNECE units and ranges, source timestamps, alarms as AlarmConditionType
events) and MQTT topics of its own (payloads valid against the shipped JSON Schemas, a
retained status, a will message), from a bounded outbox that never holds the twin up."""

from __future__ import annotations

import asyncio
import json
import signal
import socket
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drafttwin.errors import ConfigError
from drafttwin.mechanics.steady_state import kinematics
from drafttwin.twin.build import build_service
from drafttwin.twin.publish import parse_publish, publishing
from drafttwin.twin.publish.base import Publisher
from drafttwin.twin.publish.mqtt import MqttPublisher
from drafttwin.twin.publish.opcua import SUPPLY_MAX_HZ, OpcUaPublisher, channel_range
from drafttwin.twin.publish.payload import SCHEMA_FILES, iso_time, schema, utc
from drafttwin.twin.store.db import EventRow, SampleRow

from ._twin import cli, env, free_port, read_plant

jsonschema = pytest.importorskip("jsonschema")  # with the test extra (through ray)
pytestmark = pytest.mark.timeout(120)


def _validators() -> dict[str, Any]:
    """A validator per shipped schema; the status schema refers to the alarm schema by URI."""
    from referencing import Registry, Resource

    docs = {name: schema(name) for name in SCHEMA_FILES}
    registry = Registry().with_resources(
        (doc["$id"], Resource.from_contents(doc)) for doc in docs.values()
    )
    out = {}
    for name, doc in docs.items():
        jsonschema.Draft202012Validator.check_schema(doc)
        out[name] = jsonschema.Draft202012Validator(
            doc, registry=registry, format_checker=jsonschema.Draft202012Validator.FORMAT_CHECKER
        )
    return out


class Subscriber:
    """A paho subscriber to ``drafttwin/twin/#`` that keeps every message (topic, retained,
    decoded JSON)."""

    def __init__(self, port: int) -> None:
        import paho.mqtt.client as mqtt

        self.messages: list[tuple[str, bool, dict[str, Any]]] = []
        self.lock = threading.Lock()
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
        self.client.on_message = self._on_message
        self.client.on_connect = lambda c, *_: c.subscribe("drafttwin/twin/#", qos=1)
        self.client.connect("127.0.0.1", port, 30)
        self.client.loop_start()

    def _on_message(self, _c: Any, _u: Any, msg: Any) -> None:
        with self.lock:
            self.messages.append((msg.topic, bool(msg.retain), json.loads(msg.payload)))

    def of(self, suffix: str) -> list[dict[str, Any]]:
        with self.lock:
            return [m for t, _, m in self.messages if t.endswith(suffix)]

    def wait(self, suffix: str, ok: Any = lambda m: True, timeout: float = 20.0) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            found = [m for m in self.of(suffix) if ok(m)]
            if found:
                return found[-1]
            time.sleep(0.05)
        raise AssertionError(f"no {suffix} message: {self.of(suffix)[-3:]}")

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


# ---- addresses, units, times, the outbox ----------------------------------------------------
@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("opcua:tcp://127.0.0.1:4841", "bad publish address"),
        ("opcua:opc.tcp://127.0.0.1", "bad publish address"),
        ("mqtt://127.0.0.1:1883?qos=2", "qos='2'"),
        ("mqtt://127.0.0.1:1883?hz=0", "hz='0'"),
        ("mqtt://127.0.0.1:1883?hz=500", "hz='500'"),
        ("mqtt://127.0.0.1:1883?prefix=a/%23", "bad topic prefix"),
        ("opcua:opc.tcp://127.0.0.1:4841?qos=1", "unknown option 'qos'"),
        ("amqp://127.0.0.1:5672", "bad publish address"),
    ],
)
def test_bad_publish_addresses_are_refused(text: str, words: str) -> None:
    with pytest.raises(ConfigError, match="--publish") as info:
        parse_publish(text)
    assert words in str(info.value)


def test_good_publish_addresses() -> None:
    pub = parse_publish("mqtt://127.0.0.1:1883?qos=0&hz=5&prefix=hall/twin")
    assert isinstance(pub, MqttPublisher)
    assert (pub.qos, pub.prefix, pub.min_interval_s) == (0, "hall/twin", 0.2)
    assert isinstance(parse_publish("opcua:opc.tcp://localhost:4841"), OpcUaPublisher)


def test_times_are_the_samples_own_to_the_microsecond() -> None:
    ts_us = 1_795_596_978_120_001
    assert iso_time(ts_us) == "2026-11-25T08:56:18.120001Z"  # date -u -d @1795596978
    assert utc(ts_us).timestamp() * 1e6 == pytest.approx(ts_us, abs=0.5)
    assert iso_time(6_010_000) == "1970-01-01T00:00:06.010000Z"  # a replayed file's seconds


def _row(machine: str, k: int) -> SampleRow:
    v = np.full(4, float(k))
    return SampleRow(machine, k * 10_000, k, 48.47, v, v, v, v * 0)


def test_outbox_drops_the_oldest_and_bounds_the_rate() -> None:
    pub = Publisher("test", max_hz=10.0, queue_len=3)
    for k in range(5):  # alarms always enter; past 3 the oldest go
        pub.on_event(EventRow("m", "fault", k, "{}"))
    pub.on_event(EventRow("m", "silent", 9, "no sample"))  # not an alarm: no entry
    assert pub.dropped == 2 and [ev.ts_us for _, ev in pub.outbox] == [2, 3, 4]
    pub = Publisher("test", max_hz=10.0, queue_len=100)
    start = time.monotonic()
    for k in range(200):  # one call per processed sample, as fast as the twin goes
        pub.on_rows("a", [_row("a", k)], [])
        pub.on_rows("b", [_row("b", k)], [])
    took = time.monotonic() - start
    per_machine = int(took * 10.0) + 1  # at most 10 Hz (wall clock) per machine
    assert 2 <= len(pub.outbox) <= 2 * per_machine
    assert pub.outbox[0][1].seq == 0  # the first row of a machine goes out at once


class _SlowClient(Publisher):
    """A client that takes 50 ms per message (a congested link)."""

    def __init__(self) -> None:
        super().__init__("slow", max_hz=100.0, queue_len=2)
        self.offered = 0
        self.seqs: list[int] = []

    def _put(self, item: tuple[str, Any]) -> None:
        self.offered += 1
        super()._put(item)

    async def send_prediction(self, st: Any, row: SampleRow) -> None:
        await asyncio.sleep(0.05)
        self.seqs.append(row.seq)

    async def send_status(self, st: Any, status: dict[str, Any]) -> None:
        pass


def test_a_slow_client_loses_the_oldest_rows_not_the_twins(twin_files: tuple[Path, Path]) -> None:
    record, model = twin_files
    service = build_service(model, [f"replay:{record}?speed=4&machine=fa320a"], detector="none")
    slow = _SlowClient()

    async def go() -> None:
        async with publishing(service, [slow]):
            await service.run()

    asyncio.run(go())
    assert service.rows == len(read_plant(record))  # the twin processed every sample
    assert slow.dropped > 0 and slow.offered == len(slow.seqs) + slow.dropped + len(slow.outbox)
    assert slow.seqs == sorted(slow.seqs)  # what went out, in order, the newest kept


class _Recorder(Publisher):
    """Every status and prediction in the order a client receives them."""

    def __init__(self) -> None:
        super().__init__("recorder", max_hz=1000.0)
        self.sent_in_order: list[tuple[str, Any]] = []

    async def send_prediction(self, st: Any, row: SampleRow) -> None:
        self.sent_in_order.append(("prediction", row.seq))

    async def send_status(self, st: Any, status: dict[str, Any]) -> None:
        self.sent_in_order.append(("status", status["state"]))


def test_a_changed_state_goes_out_before_the_rows_it_came_with(
    twin_files: tuple[Path, Path],
) -> None:
    """The status went out once a second only: a client that read a prediction, then the
    machine's state, saw 'waiting' beside live predictions (CI, on a busy machine)."""
    record, model = twin_files
    service = build_service(model, [f"replay:{record}?speed=50&machine=fa320a"], detector="none")
    client = _Recorder()

    async def go() -> None:
        async with publishing(service, [client]):
            await service.run()

    asyncio.run(go())
    sent = client.sent_in_order
    first = next(i for i, (what, _) in enumerate(sent) if what == "prediction")
    states = [value for what, value in sent[:first] if what == "status"]
    assert states and states[-1] == "live", sent[: first + 1]


def test_speed_ranges_follow_the_kinematics(twin_files: tuple[Path, Path]) -> None:
    record, model = twin_files
    service = build_service(model, [f"replay:{record}?machine=fa320a"], detector="none")
    st = service.states["fa320a"]
    train = st.twin.train
    assert train.spec.motor is not None
    top = kinematics(train, motor_rpm=120.0 * SUPPLY_MAX_HZ / train.spec.motor.poles)
    for c in ("front", "back"):
        lo, hi = channel_range(st, c)
        assert lo == 0.0 and hi == pytest.approx(top.rollers[c].rpm, rel=1e-12)
    assert channel_range(st, "front")[1] > 2 * 1815  # above the speed at the rated supply


# ---- a running twin publishing over both ------------------------------------------------------
async def _read_opcua(port: int) -> dict[str, Any]:
    """What a client sees of machine fa320a: a prediction, its units, range, timestamp."""
    from asyncua import Client, ua

    async with Client(f"opc.tcp://127.0.0.1:{port}/", timeout=10) as client:
        idx = await client.get_namespace_index("urn:drafttwin:twin")
        node = client.get_node(ua.NodeId("fa320a.Prediction.front", idx))
        for _ in range(100):
            dv = await node.read_data_value(raise_on_bad_status=False)
            if dv.StatusCode.is_good():
                break
            await asyncio.sleep(0.1)
        eu = await client.get_node(
            ua.NodeId("fa320a.Prediction.front.EngineeringUnits", idx)
        ).read_value()
        rng = await client.get_node(ua.NodeId("fa320a.Residual.front.EURange", idx)).read_value()
        tdef = await node.read_type_definition()
        measured = await client.get_node(ua.NodeId("fa320a.Measured.front", idx)).read_data_value()
        state = await client.get_node(ua.NodeId("fa320a.Health.State", idx)).read_value()
        desc = await node.read_description()
        product = await client.get_node(
            ua.ObjectIds.Server_ServerStatus_BuildInfo_ProductName
        ).read_value()
        product_uri = await client.get_node(
            ua.ObjectIds.Server_ServerStatus_BuildInfo_ProductUri
        ).read_value()
        server_uri = (await client.get_node(ua.ObjectIds.Server_ServerArray).read_value())[0]
        ident = {}
        for _ in range(100):  # the source's identity, once it said (a replay: at once)
            ident = {p: await client.get_node(ua.NodeId(f"fa320a.Identification.{p}", idx)).read_value()
                     for p in ("SerialNumber", "ProductInstanceUri", "ComponentName")}  # fmt: skip
            if ident["SerialNumber"]:
                break
            await asyncio.sleep(0.1)
        return {"dv": dv, "eu": eu, "range": rng, "type": tdef, "measured": measured,
                "state": state, "description": desc.Text, "product": product,
                "product_uri": product_uri, "server_uri": server_uri, "ident": ident}  # fmt: skip


@pytest.mark.slow  # a twin start-up: about 8 s
def test_twin_run_publishes_over_opcua_and_mqtt(
    twin_files: tuple[Path, Path], mosquitto: int
) -> None:
    record, model = twin_files
    ua_port = free_port()
    sub = Subscriber(mosquitto)
    twin = subprocess.Popen(cli("twin", "run", "--model", str(model), "--source",
                                f"replay:{record}?speed=1&machine=fa320a", "--detector", "none", "--quiet",
                                "--publish", f"opcua:opc.tcp://127.0.0.1:{ua_port}",
                                "--publish", f"mqtt://127.0.0.1:{mosquitto}?qos=1&hz=20"),
                            env=env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert twin.stderr is not None
        line = twin.stderr.readline() + twin.stderr.readline()
        assert "publishing on opcua:" in line and "publishing on mqtt:" in line, line
        seen = asyncio.run(_read_opcua(ua_port))
        sub.wait("/status", lambda m: m["state"] == "live")
        sub.wait("/prediction", lambda m: m["channels"]["front"]["residual"] is not None)
        sub.wait("/prediction", lambda m: len(sub.of("/prediction")) >= 10)
        t0 = time.monotonic()
        twin.send_signal(signal.SIGTERM)
        out, err = twin.communicate(timeout=30)
        took = time.monotonic() - t0
    finally:
        if twin.poll() is None:
            twin.kill()
            twin.communicate(timeout=30)
        sub.close()
    assert twin.returncode == 0 and "Traceback" not in err, err
    assert "published on mqtt://" in out, out
    # OPC UA: an analog item in r/min (UNECE RPM) with a range, stamped with the sample's time
    frame = read_plant(record)
    assert seen["type"].Identifier == 2368  # AnalogItemType
    assert (seen["eu"].UnitId, seen["eu"].DisplayName.Text) == (5394509, "r/min")
    assert seen["range"].Low == -seen["range"].High and seen["range"].High > 3000
    assert seen["measured"].SourceTimestamp.year == 1970  # a replayed file's own seconds
    assert frame["ts_us"].min() <= _us(seen["measured"].SourceTimestamp) <= frame["ts_us"].max()
    assert seen["state"] in ("live", "connecting")
    assert "prediction" in seen["description"] and seen["product"] == "drafttwin twin"
    # one identity scheme: the twin's server and product URNs, the machine's Identification
    # as its source (the record's sidecar) said
    from drafttwin.wire.identity import recorded_identity

    known = recorded_identity(record)
    assert known is not None
    assert (seen["product_uri"], seen["server_uri"]) == (
        "urn:drafttwin:twin",
        "urn:drafttwin:twin:server",
    )
    assert seen["ident"]["SerialNumber"] == known.serial
    assert seen["ident"]["ProductInstanceUri"] == f"urn:drafttwin:machine:{known.serial}"
    assert seen["ident"]["ComponentName"].Text == "fa320a"
    # MQTT: every payload valid; the measured values are the file's, the residual closes
    check = _validators()
    preds, statuses = sub.of("/prediction"), sub.of("/status")
    assert len(preds) >= 10
    for m in preds:
        check["prediction"].validate(m)
    for m in statuses:
        check["status"].validate(m)
    wrong = json.loads(json.dumps(preds[-1]))
    wrong["channels"]["front"]["prediction"] = "1813.2"  # a number as text: refused
    with pytest.raises(jsonschema.ValidationError):
        check["prediction"].validate(wrong)
    by_ts = frame.set_index("ts_us")
    for m in preds:
        ts = round(m["time"] * 1e6)
        assert m["timestamp"] == iso_time(ts)
        front = m["channels"]["front"]
        assert front["unit"] == "r/min" and m["setpoint"]["unit"] == "Hz"
        assert front["measured"] == pytest.approx(by_ts.loc[ts, "front"], abs=1e-9)
        if front["residual"] is not None:
            assert front["residual"] == pytest.approx(front["measured"] - front["prediction"],
                                                      abs=1e-9)  # fmt: skip
    # the last status, retained, says offline after the clean stop; the alarms as they stand
    # are retained too, an empty list when there never was one
    late = Subscriber(mosquitto)
    try:
        last = late.wait("/status")
        standing = late.wait("/alarms")
    finally:
        late.close()
    assert last["state"] == "offline" and last["processed"] > 0
    check["alarms"].validate(standing)
    assert standing["alarms"] == [] if isinstance(standing, dict) else standing == []
    assert took < 5.0, f"{took:.1f} s from SIGTERM to the end"


def _us(t: Any) -> int:
    import datetime as dt

    return round((t.replace(tzinfo=dt.UTC) - dt.datetime(1970, 1, 1, tzinfo=dt.UTC))
                 / dt.timedelta(microseconds=1))  # fmt: skip


# ---- alarms and the will ----------------------------------------------------------------------
class _Events:
    def __init__(self) -> None:
        self.events: list[Any] = []

    def event_notification(self, event: Any) -> None:
        self.events.append(event)


def _raise(service: Any, test: str, time_s: float, cause: str) -> Any:
    """An alarm raised on the machine as the fault desk raises one, then its cause."""
    from drafttwin.diagnosis.cusum import Alarm
    from drafttwin.diagnosis.stream import Step
    from drafttwin.twin.faultwatch import alarm_detail

    st = service.states["fa320a"]
    alarm = Alarm(time_s, int(time_s), test, 1, time_s - 0.3)
    service.faults.fault_events(st, Step(alarms=[alarm]))
    element, kind = cause.split(":")
    causes = [{"element": element, "kind": kind, "family": "gear", "severity": 0.3,
               "interval": [0.2, 0.4], "probability": 0.9, "group": []}]  # fmt: skip
    ev = EventRow("fa320a", "fault-cause", int(time_s * 1e6), alarm_detail(alarm, causes))
    service.faults.cause(st, ev, causes, alarm)
    return alarm


async def _events_until(handler: _Events, n: int) -> None:
    for _ in range(200):
        if len(handler.events) >= n:
            return
        await asyncio.sleep(0.05)


async def _alarm_round(
    service: Any, ua_port: int, mqtt_port: int, sub: Subscriber
) -> dict[str, Any]:
    from asyncua import Client, ua

    opc = OpcUaPublisher("127.0.0.1", ua_port)
    mq = MqttPublisher("127.0.0.1", mqtt_port, qos=1)
    url = f"opc.tcp://127.0.0.1:{ua_port}/"
    alarm_type = ua.NodeId(ua.ObjectIds.AlarmConditionType)
    async with publishing(service, [opc, mq]):
        async with Client(url, timeout=10) as client:
            handler = _Events()
            subscription = await client.create_subscription(50, handler)
            await subscription.subscribe_alarms_and_conditions(client.nodes.server, alarm_type)
            _raise(service, "cusum:front", 4.2, "A-B:wear")
            await _events_until(handler, 2)  # the alarm, then its cause
            idx = await client.get_namespace_index("urn:drafttwin:twin")
            cause = await client.get_node(ua.NodeId("fa320a.Alarm.Cause", idx)).read_value()
            active = await client.get_node(ua.NodeId("fa320a.Alarm.Active", idx)).read_value()
        # a client that connects after the alarm: ConditionRefresh sends it the condition
        async with Client(url, timeout=10) as late:
            seen = _Events()
            subscription = await late.create_subscription(50, seen)
            await subscription.subscribe_alarms_and_conditions(late.nodes.server, alarm_type)
            await late.get_node(ua.NodeId(ua.ObjectIds.ConditionType)).call_method(
                ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh),
                ua.Variant(subscription.subscription_id, ua.VariantType.UInt32))  # fmt: skip
            await _events_until(seen, 1)
            refreshed = list(seen.events)
            condition = late.get_node(ua.NodeId("fa320a.Alarm", idx))
            event_id = refreshed[-1].EventId
            comment = ua.LocalizedText("belt checked")
            method = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)
            with pytest.raises(ua.UaStatusCodeError, match="EventIdUnknown"):
                await condition.call_method(
                    method, ua.Variant(b"not-an-event", ua.VariantType.ByteString), comment
                )
            await condition.call_method(
                method, ua.Variant(event_id, ua.VariantType.ByteString), comment
            )
            await _events_until(seen, len(refreshed) + 1)
            acked = seen.events[-1]
        # waited for in a thread: the publishers run in this event loop
        alarm = await asyncio.to_thread(sub.wait, "/alarm", lambda m: m["kind"] == "fault-cause")
        status = await asyncio.to_thread(sub.wait, "/status", lambda m: m["alarm"] is not None)
        standing = await asyncio.to_thread(sub.wait, "/alarms", lambda m: bool(m["alarms"]))
        # the twin dies (no DISCONNECT): the broker sends the machine's will message
        assert sub.of("/status")[-1]["state"] != "offline"
        mq.clients["fa320a"].socket().close()
        will = await asyncio.to_thread(sub.wait, "/status", lambda m: m["state"] == "offline")
    return {"events": handler.events, "cause": cause, "active": active, "alarm": alarm,
            "status": status, "will": will, "refreshed": refreshed, "acked": acked,
            "standing": standing, "book": service.book.retained("fa320a")}  # fmt: skip


def test_alarms_go_out_as_conditions_and_payloads_and_the_will_says_offline(
    twin_files: tuple[Path, Path], mosquitto: int
) -> None:
    record, model = twin_files
    service = build_service(model, [f"replay:{record}?machine=fa320a"], detector="none")
    sub = Subscriber(mosquitto)
    try:
        got = asyncio.run(_alarm_round(service, free_port(), mosquitto, sub))
    finally:
        sub.close()
    assert got["cause"] == "A-B:wear" and got["active"] is True
    ev = got["events"][-1]  # the condition once the cause came
    assert ev.ConditionName == "fault" and ev.Retain is True and ev.Severity == 700
    assert "A-B:wear" in ev.Message.Text and ev.Time.year == 1970
    # the late client: the condition, active and unacknowledged, through ConditionRefresh
    (late,) = [e for e in got["refreshed"] if getattr(e, "ConditionName", None)]
    assert late.Retain is True and late.ActiveState.Text == "Active"
    assert "A-B:wear" in late.Message.Text and late.AckedState.Text == "Unacknowledged"
    assert got["acked"].AckedState.Text == "Acknowledged" and got["acked"].Retain is True
    (booked,) = got["book"]
    assert booked.acked and not booked.confirmed and booked.comment == "belt checked"
    check = _validators()
    check["alarm"].validate(got["alarm"])
    assert got["alarm"]["cause"] == "A-B:wear" and got["alarm"]["time"] == 4.2
    check["status"].validate(got["status"])  # the alarm inside, by the alarm schema's URN
    assert got["status"]["alarm"]["cause"] == "A-B:wear"
    check["status"].validate(got["will"])
    check["alarms"].validate(got["standing"])  # retained: a late MQTT client reads it
    assert got["standing"]["alarms"][0]["cause"]["element"] == "A-B"
    broken = {**got["status"], "alarm": {**got["alarm"], "time": got["alarm"]["timestamp"]}}
    with pytest.raises(jsonschema.ValidationError):  # a time as text where seconds belong
        check["status"].validate(broken)


def test_a_broker_that_does_not_answer_is_a_config_error(twin_files: tuple[Path, Path]) -> None:
    record, model = twin_files
    service = build_service(model, [f"replay:{record}?machine=fa320a"], detector="none")
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]

        async def go() -> None:
            async with publishing(service, [MqttPublisher("127.0.0.1", port)]):
                pass

        with pytest.raises(ConfigError, match="cannot publish on mqtt://"):
            asyncio.run(go())
