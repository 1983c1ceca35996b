"""The leveller in the live twin (issue 39, items 2 and 3): the twin's recommendation is
``drafttwin sliver level``'s, whether the sliver comes from a replayed record or from
``plant serve --sliver`` over MQTT or OPC UA (its running count and CV with it); the twin
reads the machine's setting and never writes one."""

from __future__ import annotations

import asyncio
import contextlib
import json
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from drafttwin._json import to_strict
from drafttwin.cli import app
from drafttwin.plant import Plant
from drafttwin.plant.sliver_channel import SliverSettings
from drafttwin.sliver.leveller import Autoleveller
from drafttwin.twin.build import build_service

from ._twin import free_port

pytestmark = pytest.mark.timeout(180)
runner = CliRunner()
SETTINGS = replace(SliverSettings(), leveller=Autoleveller(1.0, 25.0), fibre_scale=4.0)


def _level(path: Path, *extra: str) -> dict[str, Any]:
    res = runner.invoke(app, ["sliver", "level", "--data", str(path), "--json", *extra])
    assert res.exit_code == 0, res.output
    doc: dict[str, Any] = json.loads(res.stdout)
    return doc


def _same(twin: dict[str, Any], offline: dict[str, Any]) -> None:
    """Equal to rounding of the float arithmetic (the same function on the same rows); a CV
    a short window cannot give (CV 5 m of 20 m) is null in both."""
    twin = to_strict(twin)
    for key in ("recommended_action_point_mm", "recommended_intensity", "metres_used",
                "current_action_point_mm", "estimated_action_point_mm", "drive_time_constant_s"):  # fmt: skip
        assert twin[key] == pytest.approx(offline[key], rel=1e-12, abs=1e-9), key
    np.testing.assert_allclose(twin["action_point_interval_mm"], offline["action_point_interval_mm"],
                               rtol=1e-12)  # fmt: skip
    for which in ("current", "recommended"):
        for key, v in offline[which].items():
            got = twin[which][key]
            assert got == v if v is None else got == pytest.approx(v, rel=1e-12), (which, key)


@pytest.fixture(scope="module")
def levelled(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Any]:
    """A plant record of 14 s (about 60 m of sliver) with its leveller 25 mm off."""
    rec = Plant().run(14.0, 100.0, seed=3, sliver=SETTINGS)
    record = tmp_path_factory.mktemp("lev") / "lev.parquet"
    rec.write(record)
    return record, rec


@pytest.mark.slow
def test_a_replayed_record_gets_sliver_levels_recommendation(twin_files, levelled) -> None:
    """Live = offline: the twin's first recommendation on a replayed record is, number for
    number, `sliver level --max-length WINDOW` on that record."""
    _, model = twin_files
    record, rec = levelled
    service = build_service(model, [f"replay:{record}?speed=inf"], detector="none",
                            level_window_m=35.0)  # fmt: skip
    asyncio.run(service.run())
    (st,) = service.states.values()
    assert st.level is not None and st.level.checks == 1  # one window in the record
    status = service.status()["machines"][st.twin.name]
    first = status["leveller"]
    assert first["state"] == "recommending" and first["setting"]["fibres"] == "record"
    assert first["window"][0] == pytest.approx(rec.sliver.delivery.delivered_length_m[0])
    _same(first["advice"], _level(record, "--max-length", "35"))
    assert [e.kind for e in st.events].count("leveller-advice") == 1
    assert status["sliver"]["count_ktex"] == pytest.approx(rec.sliver.summary["true_count_ktex"],
                                                           rel=0.01)  # fmt: skip


@pytest.mark.slow
def test_a_window_that_does_not_place_the_action_point_recommends_nothing(
    twin_files, tmp_path: Path
) -> None:
    """A leveller set 150 mm off (the least CV on the edge of the +-120-mm search): `sliver
    level` recommends nothing, while the twin's page, OPC UA nodes, MQTT state and summary
    showed its edge value as "recommending" with a zero-width interval."""
    _, model = twin_files
    rec = Plant().run(14.0, 100.0, seed=3,
                      sliver=replace(SETTINGS, leveller=Autoleveller(1.0, 150.0)))  # fmt: skip
    record = tmp_path / "edge.parquet"
    rec.write(record)
    assert _level(record, "--max-length", "35")["identifiable"] is False
    service = build_service(model, [f"replay:{record}?speed=inf"], detector="none",
                            level_window_m=35.0)  # fmt: skip
    asyncio.run(service.run())
    (st,) = service.states.values()
    lev = service.status()["machines"][st.twin.name]["leveller"]
    assert lev["state"] == "not placed" and lev["advice"]["identifiable"] is False
    assert lev["says"].startswith("leveller: no recommendation: these 35 m do not say where")
    assert "search a wider range" in lev["says"]  # its note, shown with it
    # the twin could not search wider (twin run --level-search): now it does, as sliver level
    service = build_service(model, [f"replay:{record}?speed=inf"], detector="none",
                            level_window_m=35.0, level_search_mm=250.0)  # fmt: skip
    asyncio.run(service.run())
    (st,) = service.states.values()
    lev = service.status()["machines"][st.twin.name]["leveller"]
    assert lev["state"] == "recommending", lev["says"]
    _same(lev["advice"], _level(record, "--max-length", "35", "--search", "250"))


class _Plant:
    """The plant with its sliver and leveller, served in a thread until stopped; its batches
    kept as it published them."""

    def __init__(self, kind: str, port: int) -> None:
        self.got: list[Any] = []
        self.loop: asyncio.AbstractEventLoop | None = None
        self.task: asyncio.Task[Any] | None = None
        self.thread = threading.Thread(target=self._run, args=(kind, port), daemon=True)
        self.thread.start()

    def _on_sliver(self, live: Any, batch: Any) -> None:
        self.got.append((live, batch))

    def _run(self, kind: str, port: int) -> None:
        async def main() -> None:
            self.loop = asyncio.get_running_loop()
            if kind == "mqtt":
                from drafttwin.plant.serve.mqtt import serve_mqtt

                serve: Any = serve_mqtt(f"127.0.0.1:{port}", ["m1"], physics="reduced",
                                        duration_s=120.0, broker_mode="embedded", qos=1,
                                        sliver=SETTINGS, on_sliver=self._on_sliver)  # fmt: skip
            else:
                from drafttwin.plant.serve.opcua import serve_opcua

                serve = serve_opcua(f"opc.tcp://127.0.0.1:{port}", ["m1"], physics="reduced",
                                    duration_s=120.0, sliver=SETTINGS,
                                    on_sliver=self._on_sliver)  # fmt: skip
            self.task = asyncio.ensure_future(serve)
            with contextlib.suppress(asyncio.CancelledError):  # stopped by the test
                await self.task

        asyncio.run(main())

    def stop(self) -> None:
        if self.loop is not None and self.task is not None:
            self.loop.call_soon_threadsafe(self.task.cancel)
        self.thread.join(30)


def _round_trip(kind: str, twin_files: Any, run_s: float, window_m: float) -> Any:
    from drafttwin.plant.serve.mqtt import broker_answers

    _, model = twin_files
    port = free_port()
    plant = _Plant(kind, port)
    deadline = time.monotonic() + 60
    while not (plant.got if kind == "opcua" else broker_answers("127.0.0.1", port)):
        assert plant.thread.is_alive() and time.monotonic() < deadline, "no plant"
        time.sleep(0.05)
    source = (f"mqtt://127.0.0.1:{port}?machine=m1" if kind == "mqtt"
              else f"opcua:opc.tcp://127.0.0.1:{port}?machine=m1")  # fmt: skip
    try:
        service = build_service(model, [source], detector="none", level_window_m=window_m)
        asyncio.run(service.run(duration_s=run_s))
    finally:
        plant.stop()
    got = plant.got
    # the plant's readings, as it published them
    frame = pd.DataFrame({
        "delivered_length_m": np.concatenate([b.delivered_m for _, b in got]),
        "time": np.concatenate([b.time_s for _, b in got]),
        "linear_density_ktex": np.concatenate([b.ktex for _, b in got]),
        "infeed_ktex": np.concatenate([b.infeed_ktex for _, b in got]),
        "fed_length_m": np.concatenate([b.fed_length_m for _, b in got])})  # fmt: skip
    return service, service.states["m1"], frame, got[0][0]


def _check_round_trip(service: Any, st: Any, frame: pd.DataFrame, live: Any, tmp_path: Path,
                      window_m: float) -> dict[str, Any]:  # fmt: skip
    status = service.status()["machines"]["m1"]
    lev = status["leveller"]
    assert lev is not None and lev["state"] == "recommending", lev
    setting = lev["setting"]  # as the machine published it: the leveller's own setting
    assert setting["action_point_mm"] == pytest.approx(live.leveller.action_point_mm)
    assert setting["intensity"] == 1.0 and setting["fibres"] == "record"
    lo, hi = lev["window"]
    assert hi - lo == pytest.approx(window_m, abs=0.01)
    cut = frame[(frame.delivered_length_m >= lo) & (frame.delivered_length_m <= hi)]
    path = tmp_path / "window.csv"
    cut.to_csv(path, index=False)
    offline = _level(path, "--action-point", repr(setting["action_point_mm"]), "--intensity", "1",
                     "--reference-ktex", repr(setting["reference_ktex"]))  # fmt: skip
    _same(lev["advice"], offline)
    # the live plant's leveller sits 25 mm past its true action point: the twin says so
    true = live.true_action_point_mm
    assert lev["advice"]["current_action_point_mm"] - true == pytest.approx(25.0, abs=1e-6)
    assert abs(lev["advice"]["recommended_action_point_mm"] - true) < 10.0
    assert lev["advice"]["recommended"]["cv_pct"] < lev["advice"]["current"]["cv_pct"]
    s = status["sliver"]
    assert s["count_ktex"] == pytest.approx(SETTINGS.feed.total_ktex / 6.57, rel=0.02)
    assert 0.5 < s["cv_pct"] < 3.0 and s["repeated_batches"] == 0
    assert live.leveller.action_point_mm == setting["action_point_mm"]  # nothing written
    return lev


def test_plant_serve_sliver_over_mqtt_reaches_the_twins_recommendation(twin_files, tmp_path):
    """plant serve --sliver (embedded broker, QoS 1) -> twin run over MQTT on 127.0.0.1: the
    twin's recommendation equals `sliver level` on the window's readings as published."""
    service, st, frame, live = _round_trip("mqtt", twin_files, 7.0, 18.0)
    _check_round_trip(service, st, frame, live, tmp_path, 18.0)


def test_plant_serve_sliver_over_opcua_reaches_the_twins_recommendation(twin_files, tmp_path):
    """The same over OPC UA: the twin subscribes the plant's sliver block beside the sample
    node and reads the leveller's description there."""
    service, st, frame, live = _round_trip("opcua", twin_files, 7.0, 18.0)
    _check_round_trip(service, st, frame, live, tmp_path, 18.0)


@pytest.mark.long
def test_plant_serve_sliver_over_opcua_the_spectrogram_and_the_recommendation(twin_files,
                                                                             tmp_path):  # fmt: skip
    """Over OPC UA long enough for a spectrogram of the last 100 m and two windows of the
    leveller, one after the other without a gap."""
    service, st, frame, live = _round_trip("opcua", twin_files, 32.0, 40.0)
    lev = _check_round_trip(service, st, frame, live, tmp_path, 40.0)
    assert lev["checks"] >= 2 and lev["gaps"] == 0
    s = service.status()["machines"]["m1"]["sliver"]
    assert s["delivered_m"] > 120 and s["spectrogram"] is not None
    assert len(s["spectrogram"]["wavelength_m"]) > 40


async def _published(service: Any, ua_port: int, mqtt_port: int) -> dict[str, Any]:
    """Run the twin publishing over OPC UA and MQTT (embedded broker); what clients read."""
    import paho.mqtt.client as mqtt
    from asyncua import Client, ua

    from drafttwin.plant.serve.mqtt import start_broker
    from drafttwin.twin.publish import publishing
    from drafttwin.twin.publish.mqtt import MqttPublisher
    from drafttwin.twin.publish.opcua import OpcUaPublisher

    broker = await start_broker("127.0.0.1", mqtt_port)
    opc = OpcUaPublisher("127.0.0.1", ua_port)
    pub = MqttPublisher("127.0.0.1", mqtt_port, qos=1)
    out: dict[str, Any] = {}
    try:
        async with publishing(service, [opc, pub]):
            await service.run()
            await opc.statuses(service)
            await pub.statuses(service)
            assert not opc.failed and not pub.failed, (opc.last_error, pub.last_error)
            async with Client(f"opc.tcp://127.0.0.1:{ua_port}/", timeout=10) as client:
                idx = await client.get_namespace_index("urn:drafttwin:twin")
                node = lambda key: client.get_node(ua.NodeId(f"fa320a.{key}", idx))  # noqa: E731
                for key in ("Leveller.RecommendedActionPoint", "Leveller.ActionPoint",
                            "Leveller.ExpectedCV", "Leveller.CurrentCV", "Sliver.Count", "Sliver.CV"):  # fmt: skip
                    out[key] = await node(key).read_value()
                out["state"] = await node("Leveller.State").read_value()
                out["advice"] = json.loads(await node("Leveller.Advice").read_value())
                out["eu"] = await node(
                    "Leveller.RecommendedActionPoint.EngineeringUnits"
                ).read_value()
                out["access"] = (await node("Leveller.RecommendedActionPoint").read_attribute(
                    ua.AttributeIds.UserAccessLevel)).Value.Value  # fmt: skip
            got: list[Any] = []
            sub = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
            sub.on_message = lambda c, u, m: got.append((m.topic, m.retain, m.payload))
            sub.on_connect = lambda c, *_: c.subscribe("drafttwin/twin/fa320a/sliver", qos=1)
            sub.connect("127.0.0.1", mqtt_port, 30)
            sub.loop_start()
            for _ in range(200):
                if got:
                    break
                await asyncio.sleep(0.05)
            sub.loop_stop()
            sub.disconnect()
            out["mqtt"] = got
    finally:
        await broker.shutdown()
    return out


@pytest.mark.slow
def test_the_twin_publishes_the_sliver_and_the_recommendation_read_only(twin_files, levelled):
    """Its OPC UA server (AnalogItemType in mm with the UNECE code, read only) and a retained
    MQTT message valid against the shipped schema carry the recommendation /api/status has."""
    jsonschema = pytest.importorskip("jsonschema")
    from drafttwin.twin.publish.payload import schema

    _, model = twin_files
    record, _ = levelled
    service = build_service(model, [f"replay:{record}?speed=inf&machine=fa320a"],
                            detector="none", level_window_m=35.0)  # fmt: skip
    seen = asyncio.run(_published(service, free_port(), free_port()))
    lev = service.status()["machines"]["fa320a"]["leveller"]
    advice = lev["advice"]
    assert seen["state"] == "recommending" and seen["advice"] == to_strict(advice)
    assert seen["Leveller.RecommendedActionPoint"] == advice["recommended_action_point_mm"]
    assert seen["Leveller.ActionPoint"] == advice["current_action_point_mm"]
    assert seen["Leveller.ExpectedCV"] == advice["recommended"]["cv_pct"]
    assert seen["Leveller.CurrentCV"] == advice["current"]["cv_pct"]
    assert seen["Sliver.CV"] == pytest.approx(service.states["fa320a"].sliver.cv_pct)
    assert (seen["eu"].UnitId, seen["eu"].DisplayName.Text) == (0x4D4D54, "mm")  # UNECE MMT
    assert seen["access"] & 2 == 0  # CurrentWrite: not writable; a recommendation only
    assert seen["Sliver.Count"] == pytest.approx(5.02, rel=0.02)
    # QoS 1 is at least once: a loaded broker may deliver the retained message twice
    (topic, retained, payload), *again = seen["mqtt"]
    assert all(json.loads(p)["leveller"] == json.loads(payload)["leveller"] for _, _, p in again)
    doc = json.loads(payload)
    assert topic == "drafttwin/twin/fa320a/sliver" and retained
    check = jsonschema.Draft202012Validator(schema("sliver"))
    check.validate(doc)
    assert doc["leveller"]["advice"] == to_strict(advice)
    with pytest.raises(jsonschema.ValidationError):  # the schema is strict: it can fail
        check.validate({**doc, "leveller": {**doc["leveller"], "state": "writing"}})


@pytest.mark.slow  # a plant start-up and 6 s of sliver
def test_plant_serve_sliver_stops_on_sigterm_and_its_log_is_a_leveller_record(tmp_path) -> None:
    """`plant serve --sliver --leveller 1,25 --log LOG`: SIGTERM ends it within 5 s with the
    sliver's summary; the log's sliver file and sidecar are what `sliver level --data LOG`
    reads, with the machine's setting."""
    import signal
    import subprocess

    from ._twin import cli, env

    log = tmp_path / "plant.parquet"
    plant = subprocess.Popen(cli("plant", "serve", "--mqtt", f"127.0.0.1:{free_port()}",
                                 "--physics", "reduced", "--sliver", "--leveller", "1,25",
                                 "--fibre-scale", "4", "--log", str(log)),
                             env=env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True)  # fmt: skip
    try:
        assert plant.stderr is not None
        line = plant.stderr.readline()
        assert "serving fa320a" in line, line + plant.stderr.read()
        time.sleep(6.0)
        t0 = time.monotonic()
        plant.send_signal(signal.SIGTERM)
        out, err = plant.communicate(timeout=30)
        took = time.monotonic() - t0
    finally:
        if plant.poll() is None:
            plant.kill()
            plant.communicate(timeout=30)
    assert plant.returncode == 0 and "Traceback" not in err and took < 5.0, (took, err)
    assert "sliver fa320a:" in out and "ktex, CV" in out, out
    sidecar = json.loads((tmp_path / "plant.json").read_text("utf-8"))
    assert sidecar["files"]["sliver"] == "plant.sliver.parquet"
    assert "true_action_point_mm" not in json.dumps(sidecar)
    doc = _level(log)
    assert doc["current_action_point_mm"] == sidecar["sliver"]["leveller"]["action_point_mm"]
    assert doc["fibres"]["source"] == "record" and doc["metres_used"] > 15
    # the sidecar named among what it wrote (the console wraps long paths)
    assert f"{tmp_path / 'plant.json'}" in out.replace("\n", "")
    # sliver diagnose reads the log's speeds for the encoders (it refused the log's
    # 'machine' column, naming --speeds, which nobody gave)
    res = runner.invoke(app, ["sliver", "diagnose", "--data", str(log), "--json"])
    assert res.exit_code == 0, res.output
    assert "evenness" in json.loads(res.stdout)
    # a file beside the log that an earlier log did not write is refused, not replaced
    for name, content in (("other.sliver.parquet", b"mine"), ("other.json", b'{"a": 1}')):
        (tmp_path / name).write_bytes(content)
        res = runner.invoke(app, ["plant", "serve", "--mqtt", "127.0.0.1:1", "--sliver",
                                  "--log", str(tmp_path / "other.parquet")])  # fmt: skip
        assert res.exit_code == 2 and f"{name} exists and is not" in res.output, res.output
        assert (tmp_path / name).read_bytes() == content
        assert not (tmp_path / "other.parquet").exists()
        (tmp_path / name).unlink()


def test_a_sliver_option_without_sliver_is_refused_in_one_line() -> None:
    for argv in (["--leveller", "1"], ["--fibre-scale", "4"], ["--feed-fault", "piecing=3"]):
        res = runner.invoke(app, ["plant", "serve", "--mqtt", "127.0.0.1:1", *argv])
        assert res.exit_code == 2 and "add --sliver" in res.stderr, res.output
        assert argv[0] in res.stderr and "Traceback" not in res.output
    res = runner.invoke(app, ["plant", "serve", "--mqtt", "127.0.0.1:1", "--sliver",
                              "--leveller", "one"])  # fmt: skip
    assert res.exit_code == 2 and "--leveller" in res.stderr and "INTENSITY" in res.stderr


def test_a_stop_signal_abandons_the_window_in_progress_a_natural_end_waits_for_it() -> None:
    """SIGTERM must end the twin within 5 s: a leveller's window still computing (seconds
    for 300 m) is abandoned; a replay that ends waits for it."""
    from types import SimpleNamespace

    from drafttwin.twin.sliverdesk import SliverDesk

    class Host:
        loop = None
        stop_signalled = False
        subscribers: list[Any] = []
        events: list[Any] = []

        def event(self, st: Any, ev: Any) -> None:
            self.events.append(ev)

        def report(self, *a: Any) -> None:
            pass

    class SlowLevel:
        context = SimpleNamespace(staple=None)

        def __init__(self) -> None:
            self.done = False

        def due(self) -> bool:
            return not self.done

        def take(self) -> Any:
            self.done = True
            return SimpleNamespace(time_s=np.array([1.0]))

        def check(self, record: Any) -> str:
            time.sleep(3.0)
            return "slow"

        def accept(self, record: Any, result: Any) -> None:
            self.failed = result

        def text(self) -> str:
            return "leveller: none"

    async def settle(signalled: bool, later_s: float | None = None) -> float:
        host = Host()
        host.stop_signalled = signalled
        desk = SliverDesk(host)  # type: ignore[arg-type]
        host.loop = asyncio.get_running_loop()  # type: ignore[assignment]
        st = SimpleNamespace(level=SlowLevel(), level_busy=False, twin=SimpleNamespace(name="m"))
        desk._level(st)  # type: ignore[arg-type]
        assert st.level_busy
        if later_s is not None:  # a signal while a natural end waits (a replay that ended)
            host.loop.call_later(later_s, setattr, host, "stop_signalled", True)
        t0 = time.monotonic()
        await desk.settle()
        return time.monotonic() - t0

    assert asyncio.run(settle(True)) < 0.5
    assert asyncio.run(settle(False)) > 2.5
    # it had waited for the window: 8.4-9.1 s after SIGTERM at a replay's end
    assert asyncio.run(settle(False, later_s=0.5)) < 2.0  # the window: 3 s


def test_the_leveller_worker_does_not_hold_the_process_at_exit() -> None:
    """A ThreadPoolExecutor's thread is joined at exit: a window still computing held the
    twin after its summary. The daemon worker's thread is not waited for."""
    import subprocess
    import sys

    code = ("import time\nfrom drafttwin.twin.sliverdesk import DaemonWorker\n"
            "w = DaemonWorker('leveller')\nf = w.submit(time.sleep, 30)\n"
            "g = w.submit(time.sleep, 30)\ntime.sleep(0.3)\nw.shutdown([g])\n"
            "assert g.cancelled() and f.running()\nprint(time.monotonic())\n")  # fmt: skip
    done = subprocess.run([sys.executable, "-c", code], timeout=60, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    # from its last line to its exit (one clock for both processes): a held worker adds its
    # 30-s sleep; the import before is not counted (on a loaded CI it took 11 s)
    assert time.monotonic() - float(done.stdout.split()[-1]) < 10


@pytest.mark.long  # a 40-s plant record with its sliver (171 m) and Chromium: about 60 s
def test_the_page_shows_the_sliver_its_spectrogram_and_the_recommendation(twin_files, tmp_path):
    """The page's sliver card: running count and CV, the last spectrogram (a point per
    channel, the random sliver's curve), the machine's setting and the recommendation.

    The page serves while the replay runs: the first spectrogram comes after 100 m (23 s of
    record), so the record runs on 17 s past it, at 4x (4 s of wall clock) for the page's
    1-s poll to fetch it (a 26-s record at 8x left 0.3 s, which a slow Chromium start missed)."""
    from .test_twin_page import CHROMIUM, TOKEN, _chromium, _keep_shot, _serving

    if CHROMIUM is None:
        pytest.skip("Debian's chromium is not installed")
    sync_api = pytest.importorskip("playwright.sync_api", reason="needs playwright")
    _, model = twin_files
    rec = Plant().run(40.0, 100.0, seed=3, sliver=replace(SETTINGS, fibre_scale=8.0))
    record = tmp_path / "lev.parquet"
    rec.write(record)
    service = build_service(model, [f"replay:{record}?speed=4&machine=df-01"], detector="none",
                            level_window_m=40.0)  # fmt: skip
    port = free_port()
    thread, found = _serving(service, port)
    with sync_api.sync_playwright() as p:
        browser = _chromium(p)
        page = browser.new_page(viewport={"width": 1280, "height": 1600})
        page.goto(f"http://127.0.0.1:{port}/?token={TOKEN}")
        page.wait_for_selector("#sliver .advice", timeout=60_000)
        page.wait_for_function("twinPage.spectrogram && twinPage.spectrogram.data[0].length > 20",
                               timeout=60_000)  # fmt: skip
        # the replay goes on while the page is read: the page must catch up with the status's
        # recommendation of the moment (it moved by 0.2 mm between two reads on a busy box)
        while True:
            text = page.locator("#sliver").inner_text()
            a = service.status()["machines"]["df-01"]["leveller"]["advice"]
            want = f"recommended: action point {a['recommended_action_point_mm']:.1f} mm"
            if want in text or not thread.is_alive():
                break
            time.sleep(0.25)
        points = page.evaluate("twinPage.spectrogram.data[1].filter(v => v !== null).length")
        png = page.locator("#sliver-card").screenshot()
        _keep_shot(png, "twin-sliver.png")
        browser.close()
    assert want in text, text
    assert "The twin writes no setting" in text and "the machine's setting action point" in text
    assert "count 5.0" in text and "ktex · CV" in text
    assert points > 20


def test_a_machine_without_a_leveller_is_promised_no_recommendation() -> None:
    """'no leveller; ... a recommendation every 50 m of sliver', then none ever came (a window
    without a setting is never due)."""
    from types import SimpleNamespace

    from drafttwin.plant.sliver_channel import SliverSettings
    from drafttwin.twin.sliverdesk import SliverDesk
    from drafttwin.wire.sliver import PAYLOAD_VERSION

    events: list[Any] = []

    class Host:
        loop = None
        stop_signalled = False
        subscribers: list[Any] = []

        def event(self, st: Any, ev: Any) -> None:
            events.append(ev)

        def report(self, *a: Any) -> None:
            events.append(a)

    desk = SliverDesk(Host())  # type: ignore[arg-type]
    st = SimpleNamespace(level=None, sliver=None, twin=SimpleNamespace(name="m"))
    for leveller, says in ((None, "no setting to recommend from"),
                           ({"intensity": 1.0, "action_point_mm": 720.0}, "a recommendation every")):  # fmt: skip
        section = {**SliverSettings().record(), "v": PAYLOAD_VERSION, "leveller": leveller}
        desk.describe(st, json.dumps(section))  # type: ignore[arg-type]
        assert says in events[-1].detail, events[-1]
