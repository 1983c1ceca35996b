"""The sliver on the wire is checked before it is trusted: a batch of readings (MQTT JSON, the
OPC UA block) and a machine's description are bounded and refused in one reason when they
are malformed; the plant's payloads follow the shipped schemas; the leveller's window starts
again at a gap and says why it recommends nothing."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from drafttwin.plant.live import LivePlant
from drafttwin.plant.live_sliver import LiveSliver
from drafttwin.plant.serve.sliver import DESCRIPTION_SCHEMA, SCHEMA
from drafttwin.plant.sliver_channel import SliverSettings
from drafttwin.sliver.leveller import Autoleveller
from drafttwin.sliver.levelwatch import LevelContext, LevelWatch
from drafttwin.wire.sliver import (
    MAX_READINGS,
    SliverBatch,
    from_block,
    parse_description,
    parse_sliver,
    sliver_block,
    sliver_payload,
)


@pytest.fixture(scope="module")
def served() -> tuple[LiveSliver, list[SliverBatch]]:
    """A live machine with its leveller 2 s into its run: its sliver batches."""
    plant = LivePlant(2, 100.0, physics="reduced")
    live = LiveSliver(plant, replace(SliverSettings(), leveller=Autoleveller(1.0, -10.0),
                                     fibre_scale=16.0), 2, "m1")  # fmt: skip
    batches = []
    for _ in range(200):
        plant.step()
        b = live.after()
        if b is not None:
            batches.append(b)
    return live, batches


def test_the_plants_payloads_follow_the_schemas_and_come_back_whole(served) -> None:
    jsonschema = pytest.importorskip("jsonschema")
    live, batches = served
    assert len(batches) >= 15 and all(b.time_s.size > 100 for b in batches)
    check = jsonschema.Draft202012Validator(json.loads(Path(SCHEMA).read_text("utf-8")))
    for b in batches:
        doc = sliver_payload(b)
        check.validate(doc)
        back = parse_sliver("m1", json.dumps(doc).encode())
        assert isinstance(back, SliverBatch) and back.seq == b.seq
        for x, y in zip(back.arrays, b.arrays, strict=True):
            np.testing.assert_array_equal(x, y)  # rounded once, exact on the way back
        block = from_block("m1", sliver_block(b))
        assert isinstance(block, SliverBatch)
        np.testing.assert_array_equal(block.ktex, b.ktex)
    with pytest.raises(jsonschema.ValidationError):
        check.validate({**sliver_payload(batches[0]), "n": 0})
    described = live.describe()
    jsonschema.Draft202012Validator(
        json.loads(Path(DESCRIPTION_SCHEMA).read_text("utf-8"))
    ).validate(described)
    assert "true_action_point_mm" not in json.dumps(described)  # the machine does not know it
    s = np.concatenate([b.delivered_m for b in batches])
    assert np.allclose(np.diff(s), 0.002)  # a reading every 2 mm, none lost between batches


def _payload(**change: object) -> bytes:
    doc = {"v": 1, "seq": 3, "timestamp": "2026-01-01T00:00:00.000000Z", "n": 3,
           "time": [1.0, 1.0005, 1.001], "delivered_length_m": [0.0015, 0.0035, 0.0055],
           "linear_density_ktex": [5.0, 5.01, 4.99], "infeed_ktex": [33.0, 33.1, 32.9],
           "fed_length_m": [0.0002, 0.0005, 0.0008], **change}  # fmt: skip
    return json.dumps(doc).encode()


@pytest.mark.parametrize(("change", "why"), [
    ({"n": 4}, "fields missing"),
    ({"n": True}, "reading count"),
    ({"seq": 1.5}, "fields missing"),
    ({"seq": -1}, "fields missing"),
    ({"linear_density_ktex": [5.0, "5.01", 4.99]}, "fields missing"),
    ({"linear_density_ktex": [5.0, True, 4.99]}, "fields missing"),
    ({"linear_density_ktex": [5.0, 0.0, 4.99]}, "fields missing"),
    ({"linear_density_ktex": [5.0, 1e300, 4.99]}, "fields missing"),
    ({"delivered_length_m": [0.0015, 0.0015, 0.0055]}, "fields missing"),
    ({"fed_length_m": [0.0002, 0.0001, 0.0008]}, "fields missing"),
    ({"time": [1.0, 0.5, 1.001]}, "fields missing"),
    ({"v": 2}, "version-1"),
    ({"n": MAX_READINGS + 1}, "fields missing"),
])  # fmt: skip
def test_a_malformed_sliver_payload_is_dropped_with_its_reason(change: dict, why: str) -> None:
    got = parse_sliver("m1", _payload(**change))
    assert isinstance(got, str) and why in got


def test_hostile_sliver_bytes_and_blocks_are_dropped() -> None:
    assert "not JSON" in str(parse_sliver("m1", b"\xff\xfe{"))
    assert "bytes" in str(parse_sliver("m1", b" " * 400_001))
    assert "[[[[" not in str(parse_sliver("m1", b"[" * 100_000))  # no RecursionError
    ok = parse_sliver("m1", _payload(infeed_ktex=None, fed_length_m=None))
    assert isinstance(ok, SliverBatch) and np.isnan(ok.infeed_ktex).all()  # a machine without
    assert isinstance(from_block("m1", [1.0, 2.0, 1.0]), str)  # length does not hold n readings
    assert isinstance(from_block("m1", [1.0, float("nan")]), str)
    assert isinstance(from_block("m1", "text"), str)


def test_a_description_is_bounded_and_its_values_checked() -> None:
    assert "bytes" in str(parse_description("x" * 20_000))
    assert "version-1" in str(parse_description(json.dumps({"v": 2})))
    good = {"v": 1, "staple": {"name": "cotton", "mean_length_mm": 24.0, "length_cv": 0.33,
                               "fineness_dtex": 1.6, "fineness_cv": 0.25},
            "doublings": 6, "feed_ktex": 5.5, "delivery_sensor": {"averaging_mm": 5.0},
            "leveller": {"intensity": 1.0, "action_point_mm": 700.0}}  # fmt: skip
    ctx = LevelContext.of(good)
    assert ctx.setting is not None and ctx.setting.reference_ktex == 33.0
    assert ctx.fibres == "record" and ctx.delivery is not None
    for bad in ({"intensity": 1.0, "action_point_mm": 1e300},
                {"intensity": float("nan"), "action_point_mm": 700.0},
                {"intensity": 5.0, "action_point_mm": 700.0}):  # fmt: skip
        assert LevelContext.of({**good, "leveller": bad}).setting is None
    odd = LevelContext.of({**good, "staple": {**good["staple"], "mean_length_mm": 1e300}})
    assert odd.fibres == "assumed"  # no fibre is that long: the cotton preset, said so
    assert LevelContext.of({**good, "delivery_sensor": {"noise": 7}}).delivery is None


def test_the_leveller_window_starts_again_at_a_gap_and_says_why_it_recommends_nothing(
    served,
) -> None:
    live, batches = served
    ctx = LevelContext.of(live.describe())
    watch = LevelWatch(ctx, window_m=20.0)
    assert watch.state == "collecting"
    for b in batches[:5]:
        watch.push(b.delivered_m, b.ktex, b.time_s, b.infeed_ktex, b.fed_length_m)
    before = watch.collected_m
    b = batches[7]  # two batches lost on the way
    watch.push(b.delivered_m, b.ktex, b.time_s, b.infeed_ktex, b.fed_length_m)
    assert watch.gaps == 1 and watch.collected_m < before
    for b in batches[8:]:
        watch.push(b.delivered_m, b.ktex, b.time_s, b.infeed_ktex, b.fed_length_m)
    assert not watch.due()  # 2 s of running: about 9 m, not 20
    short = LevelWatch(ctx, window_m=20.0)
    for b in batches:
        short.push(b.delivered_m, b.ktex, b.time_s, b.infeed_ktex, b.fed_length_m)
    record = short.take()
    short.accept(record, short.check(record))  # a window of a few metres says nothing
    assert short.advice is None and "store's reach" in str(short.failed)
    none = LevelWatch(LevelContext.of({**live.describe(), "leveller": None}))
    none.push(b.delivered_m, b.ktex, b.time_s, b.infeed_ktex, b.fed_length_m)
    assert none.state == "no leveller" and not none.due()


def test_the_mqtt_source_counts_a_hostile_sliver_or_description_as_dropped(served) -> None:
    """The network thread's checks: a malformed batch is a drop with its reason, a good one is
    a batch for the twin, the description is handed over as text (checked by the twin)."""
    import asyncio
    from types import SimpleNamespace

    from drafttwin.twin.sources.mapping import MachineMap
    from drafttwin.twin.sources.mqtt import MqttSource

    _, batches = served
    m = MachineMap("m1", ("front", "second", "third", "back"))
    src = MqttSource("127.0.0.1", 1, (m,))
    emitted, reported = [], []
    loop = asyncio.new_event_loop()
    try:
        src.bind(loop, emitted.append, lambda *a: reported.append(a))
        for payload in (_payload(n=4), b"\xff", json.dumps(sliver_payload(batches[0])).encode()):
            src.on_message(
                None, None, SimpleNamespace(topic="drafttwin/m1/sliver", payload=payload)
            )
        src.on_message(None, None, SimpleNamespace(topic="drafttwin/m1/leveller",
                                                   payload=b"x" * 50_000))  # fmt: skip
        loop.run_until_complete(asyncio.sleep(0.01))
    finally:
        loop.close()
    assert [type(e).__name__ for e in emitted] == ["SliverBatch"]
    drops = [r for r in reported if r[1] == "dropped"]
    assert len(drops) == 2 and "fields missing" in drops[0][2] and "not JSON" in drops[1][2]
    (lev,) = [r for r in reported if r[1] == "leveller"]
    assert len(lev[2]) == 16_385  # cut at the limit + 1: the twin refuses it by its size
    assert "bytes" in str(parse_description(lev[2]))


def test_a_description_said_again_keeps_the_window_a_new_one_starts_it_again(served) -> None:
    """A reconnect or a retained message repeats the description: the leveller's window goes
    on; another setting starts a new one (the window's rows are of one setting)."""
    import asyncio
    from types import SimpleNamespace

    from drafttwin.twin.sliverdesk import SliverDesk

    live, batches = served
    reported: list[tuple[str, ...]] = []
    host = SimpleNamespace(loop=None, subscribers=[], event=lambda st, ev: None,
                           report=lambda *a: reported.append(a), stop_signalled=True)  # fmt: skip
    desk = SliverDesk(host, window_m=20.0)  # type: ignore[arg-type]
    from drafttwin.mechanics import DriveTrain

    twin = SimpleNamespace(name="m1", train=DriveTrain.preset("fa320a"))
    st = SimpleNamespace(twin=twin, level=None, sliver=None, sliver_seq=-1,
                         sliver_repeated=0, sliver_busy=False, level_busy=False,
                         baseline=None, watch=None)  # fmt: skip
    text = json.dumps(live.describe())
    desk.describe(st, text)  # type: ignore[arg-type]
    first = st.level
    for b in batches[:5]:
        desk.batch(st, b)  # type: ignore[arg-type]
    desk.describe(st, text)  # type: ignore[arg-type]
    assert st.level is first and first.collected_m > 0
    desk.batch(st, batches[2])  # type: ignore[arg-type]  # QoS 1 sent it twice
    assert st.sliver_repeated == 1
    other = {**live.describe(), "leveller": {"intensity": 1.0, "action_point_mm": 650.0}}
    desk.describe(st, json.dumps(other))  # type: ignore[arg-type]
    assert st.level is not first and st.level.context.setting.action_point_mm == 650.0
    desk.describe(st, "{not json")  # type: ignore[arg-type]
    assert reported and reported[-1][1] == "dropped"
    asyncio.run(desk.settle())
