"""The page in headless Chromium (Debian's, driven by Playwright), checked on what it draws: a
record with encoder spikes keeps each roller's axis within a few rpm of its band (the spikes
marked at the edge), the legends read numbers with units on a wall-clock axis, the health
summary says live, late, data age and p99, and every retained alarm shows as a banner, most
severe first, with its probable cause: acknowledged, returned to normal, confirmed, gone. The token guards REST, the WebSocket and
/metrics; a page off 127.0.0.1 without a token is refused."""

from __future__ import annotations

import asyncio
import io
import json
import re
import shutil
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from drafttwin.cli import app
from drafttwin.twin.build import build_service
from drafttwin.twin.service import TwinService
from drafttwin.twin.web.server import serve_with

from ._twin import free_port

pytestmark = pytest.mark.timeout(150)
TOKEN = "t0ken-for-the-page-test-0123456789"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


def _get(url: str, headers: dict[str, str] | None = None) -> tuple[int, bytes]:
    req = urllib.request.Request(url, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=10) as r:  # noqa: S310  a local test server
            return r.status, r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


def _keep_shot(png: bytes, name: str) -> None:
    """The screenshot kept for a person to look at, where DRAFTTWIN_SHOTS names a folder."""
    import os

    folder = os.environ.get("DRAFTTWIN_SHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        (Path(folder) / name).write_bytes(png)


async def _ws_refused(url: str) -> bool:
    import websockets

    try:
        async with websockets.connect(url) as ws:
            await asyncio.wait_for(ws.recv(), 5)
    except websockets.exceptions.InvalidStatus:
        return True  # refused before the upgrade
    except websockets.exceptions.ConnectionClosed as exc:
        return exc.rcvd is not None and exc.rcvd.code == 1008
    return False


def test_a_public_bind_without_token_is_refused(twin_files: tuple[Path, Path]) -> None:
    record, model = twin_files
    res = CliRunner().invoke(app, ["twin", "run", "--model", str(model), "--source",
                                   f"replay:{record}", "--http", "0.0.0.0:8050"])  # fmt: skip
    assert res.exit_code == 2
    assert "refusing to serve the page on 0.0.0.0 without a token" in res.stderr


def _spiky_record(folder: Path) -> tuple[Path, np.ndarray, np.ndarray]:
    """A steady plant record with 3 % encoder spikes per roller (15-40 %, i.e. +-270-730 rpm on
    the front roller), stamped on the wall clock from now: (file, times s, front spike mask)."""
    import dataclasses

    from drafttwin.data.io import write_measurements
    from drafttwin.plant import Plant
    from drafttwin.plant.config import PlantConfig, Sensors

    rec = Plant(config=PlantConfig(sensors=Sensors(outlier_rate=0.03))).run(12.0, 100.0, seed=3)
    series = rec.series
    times = series.time_s + round(time.time())
    path = folder / "spiky.parquet"
    write_measurements(dataclasses.replace(series, time_s=times), path)
    return path, times, rec.outlier[:, 0]


def _serve(service: TwinService, port: int) -> tuple[threading.Thread, dict[str, object]]:
    """The twin and its page in a thread of their own: a busy event loop must not hold up the
    browser's driver (nor the other way round)."""
    found: dict[str, object] = {}

    def run() -> None:
        async def go() -> None:
            found["loop"] = asyncio.get_running_loop()
            await serve_with(service, ("127.0.0.1", port), TOKEN, 300, None,
                             lambda _: found.setdefault("up", True))  # fmt: skip

        asyncio.run(go())

    thread = threading.Thread(target=run, name="twin-page", daemon=True)
    thread.start()
    return thread, found


def _serving(service: TwinService, port: int) -> tuple[threading.Thread, dict[str, object]]:
    """:func:`_serve`, returned once the page listens."""
    thread, found = _serve(service, port)
    deadline = time.monotonic() + 30
    while not found.get("up"):
        assert time.monotonic() < deadline and thread.is_alive(), "the page did not start"
        time.sleep(0.05)
    return thread, found


def _chromium(p: Any) -> Any:
    """Debian's Chromium under Playwright, without its background traffic."""
    return p.chromium.launch(executable_path=CHROMIUM, args=[
        "--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--no-first-run"])  # fmt: skip


RAISED: dict[str, object] = {}
"""The alarms _alarm raised, by test (to return them to normal)."""


def _alarm(service: TwinService, test: str, cause: dict[str, object] | None) -> None:
    """An alarm (and its probable cause) through the service's own event path, at the newest
    row's time: what the detector's fault events go through (test_twin_faults.py raises them
    from a faulted plant; here the page's part is checked). ``stuck_*``: a sensor rule's."""
    from drafttwin.diagnosis.cusum import Alarm
    from drafttwin.diagnosis.stream import Step, Window
    from drafttwin.twin.faultwatch import alarm_detail
    from drafttwin.twin.store.db import EventRow

    st = service.states["df-01"]
    t = st.recent[-1].ts_us / 1e6
    sensor = test.startswith("stuck_")
    alarm = Alarm(time_s=t, block=0, test=test, direction=0 if sensor else -1, change_s=t - 3.0,
                  rule="sensor" if sensor else "cusum")  # fmt: skip
    RAISED[test] = alarm
    # a sensor rule's step brings the block that raised it (its cause is sized on it when the
    # watch has started by then: a race the test must not depend on)
    runs = np.where(np.arange(5) == 3, 150.0, 5.0)
    block = Window(t, 0, np.zeros(8), np.zeros(5), runs, runs)
    events = service.faults.fault_events(st, Step(alarms=[alarm], blocks={0: block}))
    for push in service.subscribers:
        push("df-01", [], events)
    if cause is not None:
        ev = EventRow("df-01", "fault-cause", int(round(t * 1e6)), alarm_detail(alarm, [cause]))
        service.faults.cause(st, ev, [cause], alarm)


def _normal(service: TwinService, test: str) -> None:
    """The alarm on ``test`` returned to normal (as diagnosis.clearance finds it)."""
    service.faults.cleared(service.states["df-01"], RAISED[test], "returned to normal")  # type: ignore[arg-type]


FRONT = "twinPage.charts.find(c => c.kind === '{}' && c.channel === 'front').u"
NUMBER_RPM = re.compile(r"^-?\d+\.\d rpm$")


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed "
                    "(apt-get install chromium): the browser test needs it")  # fmt: skip
def test_the_page_scales_past_spikes_and_raises_the_alarm_banner(
    twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    sync_api = pytest.importorskip("playwright.sync_api", reason="needs playwright (test extra)")
    _, model = twin_files
    record, times, spikes = _spiky_record(tmp_path)
    first_spike = float(times[np.flatnonzero(spikes)[0]])
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    service = build_service(model, [f"replay:{record}?speed=1&machine=df-01"])
    thread, found = _serving(service, port)
    try:
        assert _get(base + "/api/status")[0] == 401
        code, body = _get(base + "/metrics", {"Authorization": f"Bearer {TOKEN}"})
        assert code == 200 and b"drafttwin_samples_total" in body
        assert asyncio.run(_ws_refused(f"ws://127.0.0.1:{port}/ws"))
        loop = found["loop"]
        with sync_api.sync_playwright() as p:
            browser = _chromium(p)
            page = browser.new_page(viewport={"width": 1280, "height": 1100})
            page.goto(f"{base}/?token={TOKEN}")
            # past the record's first front-roller spike (and two samples after it)
            page.wait_for_function(f"(() => {{ const b = twinPage.machines['df-01']; return "
                                   f"twinPage.charts.length && b && b.t.length && b.t[b.t.length - 1] > {first_spike + 0.02}; }})()",
                                   timeout=60_000)  # fmt: skip
            page.wait_for_timeout(400)  # a redraw
            drawn = page.evaluate(f"""(() => {{ const u = {FRONT.format("speed")}, r = {FRONT.format("residual")};
                const b = twinPage.machines['df-01'];
                return {{ y: [u.scales.y.min, u.scales.y.max], x: [u.scales.x.min, u.scales.x.max],
                          time: u.scales.x.time, t: b.t, front: b.meas[0], marked: u.spikesShown,
                          res: [r.scales.y.min, r.scales.y.max], limit: r.limit }}; }})()""")  # fmt: skip
            limit_note = page.locator(".card[data-channel='front'] .limit").inner_text()
            legend = page.locator(".card").first.locator(".u-legend").first
            values = legend.locator(".u-value").all_text_contents()
            page.wait_for_function("twinPage.status !== null", timeout=10_000)
            page.wait_for_timeout(300)  # the tiles redrawn with it
            tile = page.locator(".tile[data-machine='df-01']").inner_text()
            loop.call_soon_threadsafe(  # type: ignore[attr-defined]
                _alarm, service, "belt", {"element": "main_belt", "kind": "belt_wear",
                                          "severity": 0.5, "interval": [0.4, 0.6],
                                          "probability": 0.9})  # fmt: skip
            banners = page.locator("#banner .banner")
            page.wait_for_selector("#banner .banner.active-unack", timeout=20_000)
            # a sensor fault after it: both shown, the machine fault (more severe) first
            loop.call_soon_threadsafe(_alarm, service, "stuck_back", None)  # type: ignore[attr-defined]
            page.wait_for_function("document.querySelectorAll('#banner .banner').length === 2",
                                   timeout=10_000)  # fmt: skip
            two = banners.all_inner_texts()
            png = page.screenshot()
            _keep_shot(png, "twin-two-alarms.png")
            belt = "#banner .banner[data-alarm*=':belt']"
            page.click(f"{belt} .ack")
            page.wait_for_selector(f"{belt}.active-ack", timeout=5_000)
            acked = page.locator(belt).inner_text()
            still = page.locator("#banner .banner[data-alarm*='stuck_back']").get_attribute("class")
            loop.call_soon_threadsafe(_normal, service, "belt")  # type: ignore[attr-defined]
            page.wait_for_selector(f"{belt}.rtn-ack", timeout=10_000)
            page.click(f"{belt} .confirm")
            page.wait_for_function("document.querySelectorAll('#banner .banner').length === 1",
                                   timeout=5_000)  # fmt: skip
            left = banners.all_inner_texts()
            page.wait_for_timeout(1500)  # a poll of /api/alarms/active: the same
            left_after_poll = banners.all_inner_texts()
            hub = page.evaluate("fetch('docs').then(r => r.text())")
            # an hour from the history API, then a zoom by dragging: every chart follows
            page.click("button[data-span='3600']")
            page.wait_for_function("twinPage.history && twinPage.history.buf.t.length > 0")
            hour = page.evaluate("[twinPage.view.live, twinPage.view.x1 - twinPage.view.x0]")
            box = page.locator(".u-over").first.bounding_box()
            assert box is not None
            page.mouse.move(box["x"] + 100, box["y"] + 40)
            page.mouse.down()
            page.mouse.move(box["x"] + 300, box["y"] + 40, steps=4)
            page.mouse.up()
            zoomed = page.evaluate("twinPage.charts.map(c => [c.u.scales.x.min, c.u.scales.x.max])")
            page.dblclick(".u-over >> nth=0")
            back_live = page.evaluate("twinPage.view.live")
            # the API docs render the endpoints (Swagger UI 4 had refused FastAPI's OpenAPI 3.1:
            # "Unable to render this definition")
            page.goto(f"{base}/docs?token={TOKEN}")
            page.wait_for_selector(".opblock-summary-path", timeout=20_000)
            documented = page.locator(".opblock-summary-path").all_inner_texts()
            browser.close()
    finally:
        service.stop()
        thread.join(timeout=30)
    # the axis: the roller's band in view (the record's own spike mask left out) with a margin
    # of a few rpm; the spikes in view lie hundreds of rpm outside and are marked at the edge
    t, front = np.array(drawn["t"], dtype=float), np.array(drawn["front"], dtype=float)
    in_view = (t >= drawn["x"][0]) & (t <= drawn["x"][1])
    spike_at = np.isin(np.round(t, 3), np.round(times[spikes], 3))
    band = front[in_view & ~spike_at & np.isfinite(front)]
    lo, hi = drawn["y"]
    assert (
        band.min() - 6 < lo <= np.quantile(band, 0.01)
        and np.quantile(band, 0.99) <= hi < band.max() + 6
    )
    assert hi - lo < 25, drawn["y"]  # a few rpm, not +-700
    off = front[in_view & spike_at]
    assert len(off) >= 1 and np.all((off < lo - 100) | (off > hi + 100)), off
    assert drawn["marked"] >= len(off)
    assert drawn["time"] is True  # the plant's clock: a wall-clock axis
    # the residual: a band around zero, its limits drawn, spikes not on the scale
    assert drawn["res"][0] == -drawn["res"][1] and 0 < drawn["res"][1] < 25
    assert drawn["limit"] is not None and 0 < drawn["limit"] < drawn["res"][1]
    # named under the chart (on the line it sat under the spike markers' values)
    assert re.search(r"(detector limit|band of the window) ±\d+\.\d\d rpm$", limit_note), limit_note
    # legend values: a wall-clock time, then numbers with units
    assert re.fullmatch(r"\d\d:\d\d:\d\d\.\d{3}", values[0]), values
    assert len(values) == 4 and all(NUMBER_RPM.match(v) for v in values[1:]), values
    for part in ("live", "late 0", "data age", " s", "p99", " ms", "set-point", " Hz"):
        assert part in tile, tile
    assert len(two) == 2, two
    assert "ALARM" in two[0] and "main_belt belt_wear" in two[0] and "belt down" in two[0]
    assert "sensor fault stuck_back" in two[1] and "probable cause pending" in two[1]
    assert "acknowledged" in acked and "main_belt" in acked and "Confirm" in acked
    assert still is not None and "active-unack" in still  # only the one acknowledged
    assert len(left) == 1 and "stuck_back" in left[0] and left_after_poll == left
    assert "docs-files/swagger-ui-bundle.js" in hub and "cdn" not in hub.lower()
    assert hour == [False, 3600]
    assert len({tuple(z) for z in zoomed}) == 1 and 100 < zoomed[0][1] - zoomed[0][0] < 3000
    assert back_live is True
    assert "/api/status" in documented and "/api/history/{machine}" in documented, documented
    import matplotlib.image as mpimg

    img = mpimg.imread(io.BytesIO(png), format="png")[..., :3]

    def pixels(hex_colour: str) -> int:
        rgb = np.array([int(hex_colour[i : i + 2], 16) for i in (1, 3, 5)]) / 255.0
        return int((np.abs(img - rgb) < 0.08).all(axis=-1).sum())

    assert pixels("#d9480f") > 200  # the twin's lines
    assert pixels("#1f6fd1") > 100  # the physics lines (dashed, on top)
    assert pixels("#c2185b") > 20  # the spike markers
    assert pixels("#b00020") + pixels("#d0303f") > 5000  # the alarm banner (blinking)
    json.dumps(service.status())


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed "
                    "(apt-get install chromium): the browser test needs it")  # fmt: skip
def test_the_hall_page_shows_each_machine_health_and_alarm_banners() -> None:
    """The hall page, built from the same script: a tile per machine with its health, a banner
    per retained alarm of every shard's machines (one active, one returned to normal and not yet
    acknowledged), most severe first, each with its button, which acknowledges through the
    machine's shard."""
    sync_api = pytest.importorskip("playwright.sync_api", reason="needs playwright (test extra)")
    from drafttwin.twin.web.hall import HallServer, HallView

    now = time.time()
    cause = {"element": "main_belt", "kind": "belt_wear", "severity": 0.5, "probability": 0.9}
    booked = {"machine": "m-1", "rule": "cusum", "change_s": None, "active": True,
              "acked": False, "confirmed": False, "cleared_s": None, "cleared_why": "",
              "comment": "", "retained": True}  # fmt: skip
    recent = {**booked, "id": "m-1:1:belt", "kind": "fault", "test": "belt", "time_s": now - 2,
              "severity": 700, "direction": -1, "cause": cause}  # fmt: skip
    old = {**booked, "id": "m-2:1:stuck_back", "machine": "m-2", "kind": "sensor-fault",
           "test": "stuck_back", "time_s": now - 300, "severity": 500, "direction": 0,
           "rule": "sensor", "active": False, "cleared_s": now - 200,
           "cause": {"element": "back", "kind": "encoder_stuck", "probability": 1.0}}  # fmt: skip
    machine = {"received": 10, "processed": 10, "dropped": 0, "fault_detector": True,
               "late": 0, "source": "x"}  # fmt: skip
    view = HallView(2)
    view.update([{"rows": 20, "latency_ms": {"p50": 1.0, "p99": 1.5, "max": 2.0}, "machines": {
        "m-1": {**machine, "state": "live", "fault_alarms": 1, "active_alarms": [recent]},
        "m-2": {**machine, "state": "silent", "fault_alarms": 1, "active_alarms": [old]}}}, None])  # fmt: skip
    taken: list[tuple] = []

    def command(shard: int, kind: str, name: str, args: dict) -> dict:
        taken.append((shard, kind, name, args["alarm"]))
        return {"status": 200, "body": {"machine": name, "taken": 1,
                                        "alarms": [{**recent, "acked": True}]}}  # fmt: skip

    view.bind_commands(command)
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    with HallServer(view, ("127.0.0.1", port), None):
        assert _get(base + "/static/twin.js")[0] == 200  # the script both pages share
        code, docs = _get(base + "/docs")
        assert code == 200 and b"docs-files/swagger-ui.css" in docs
        assert _get(base + "/docs-files/swagger-ui-bundle.js")[0] == 200
        assert _get(base + "/docs-files/..%2Fswagger-ui.js")[0] == 404
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=[
                "--no-sandbox", "--disable-gpu", "--no-first-run"])  # fmt: skip
            page = browser.new_page(viewport={"width": 1000, "height": 500})
            page.goto(base + "/")
            page.wait_for_selector("#banner .banner.rtn-unack", timeout=20_000)
            tiles = {
                m: page.locator(f".tile[data-machine='{m}']").inner_text() for m in ("m-1", "m-2")
            }
            texts = page.locator("#banner .banner").all_inner_texts()
            buttons = page.locator("#banner button").all_inner_texts()
            _keep_shot(page.screenshot(), "hall.png")
            page.click("#banner .banner[data-alarm='m-1:1:belt'] .ack")
            deadline = time.monotonic() + 10
            while not taken and time.monotonic() < deadline:
                page.wait_for_timeout(100)
            classes = {m: page.locator(f".tile[data-machine='{m}']").get_attribute("class")
                       for m in ("m-1", "m-2")}  # fmt: skip
            browser.close()
    assert len(texts) == 2, texts
    assert "m-1" in texts[0] and "main_belt belt_wear" in texts[0] and "ALARM" in texts[0]
    assert "m-2" in texts[1] and "returned to normal" in texts[1]
    assert "back encoder_stuck" in texts[1]
    assert buttons == ["Acknowledge", "Acknowledge"]  # the hall had shown them without
    assert taken == [(0, "acknowledge", "m-1", "m-1:1:belt")]  # through m-1's shard
    assert "alarm-active-unack" in str(classes["m-1"]) and "alarm-rtn-unack" in str(classes["m-2"])
    # the hall's status carries no late count nor data age (yet): the tile says "–" for the age
    assert all(p in tiles["m-1"] for p in ("live", "p99 1.5 ms", "data age")), tiles
    assert "silent" in tiles["m-2"] and "main_belt" in tiles["m-1"], tiles


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed "
                    "(apt-get install chromium): the browser test needs it")  # fmt: skip
def test_the_page_says_no_sample_yet_then_draws_with_the_first(
    twin_files: tuple[Path, Path], mosquitto: int
) -> None:
    """A machine subscribed to but silent: a note with its state instead of empty axes at
    -1..0 s; its first samples build the charts on the page already open."""
    sync_api = pytest.importorskip("playwright.sync_api", reason="needs playwright (test extra)")
    import paho.mqtt.client as mqtt

    _, model = twin_files
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    service = build_service(model, [f"mqtt://127.0.0.1:{mosquitto}?machine=df-01"])
    thread, found = _serving(service, port)
    try:
        with sync_api.sync_playwright() as p:
            browser = _chromium(p)
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.goto(f"{base}/?token={TOKEN}")
            page.wait_for_function("twinPage.status !== null && document.getElementById("
                                   "'no-samples-text') && document.getElementById("
                                   "'no-samples-text').textContent.includes('waiting')",
                                   timeout=20_000)  # fmt: skip
            before = page.evaluate("[twinPage.charts.length, document.querySelectorAll('.card[data-channel]')"
                                   ".length, document.getElementById('no-samples').innerText]")  # fmt: skip
            client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
            client.connect("127.0.0.1", mosquitto, 30)
            client.loop_start()
            now = time.time()
            for k in range(300):  # 3 s at 100 Hz
                sample = {"seq": k, "time": now + k / 100, "front": 1814.0, "second": 434.2,
                          "third": 425.7, "back": 354.8, "motor": 1449.9, "supply_hz": 48.47}  # fmt: skip
                client.publish("drafttwin/df-01/sample", json.dumps(sample), qos=1)
            page.wait_for_function("twinPage.charts.length > 0 && "
                                   "twinPage.machines['df-01'].t.length > 0", timeout=30_000)  # fmt: skip
            after = page.evaluate("[twinPage.charts.length, document.querySelectorAll('.card[data-channel]')"
                                  ".length, document.getElementById('no-samples') === null]")  # fmt: skip
            for k in range(300, 400):  # 7 s later: a gap the lines must not bridge
                sample = {"seq": k, "time": now + 7 + k / 100, "front": 1814.0, "second": 434.2,
                          "third": 425.7, "back": 354.8, "motor": 1449.9, "supply_hz": 48.47}  # fmt: skip
                client.publish("drafttwin/df-01/sample", json.dumps(sample), qos=1)
            page.wait_for_function("twinPage.machines['df-01'].t.some(t => t > "
                                   f"{now + 7 + 3.5})", timeout=30_000)  # fmt: skip
            # a narrow window: one column, the charts as wide as its cards (they were 520 px
            # in a 700-px card; three columns on a wide one overflowed theirs)
            fits = {}
            for width in (760, 1900):
                page.set_viewport_size({"width": width, "height": 900})
                page.reload()
                page.wait_for_function("twinPage.charts.length > 0", timeout=30_000)
                fits[width] = page.evaluate("""[...document.querySelectorAll('.card[data-channel]')]
                    .map(c => [c.querySelector('.uplot').offsetWidth, c.clientWidth])""")
            gap = page.evaluate("""(() => { const b = twinPage.machines['df-01'];
                const i = b.t.findIndex((t, k) => k > 0 && t - b.t[k - 1] > 2);
                return [b.t[i] - b.t[i - 1], b.meas[0][i - 1], b.twin[0][i - 1], b.t[i - 1] - b.t[i - 2]]; })()""")  # fmt: skip
            client.loop_stop()
            client.disconnect()
            browser.close()
    finally:
        service.stop()
        thread.join(timeout=30)
    assert before[0] == 0 and before[1] == 0, before
    assert "df-01: no sample yet" in before[2] and "state waiting" in before[2], before
    # four rollers (two charts each) and the set-point
    assert after[0] == 9 and after[1] == 4 and after[2] is True, after
    for width, cards in fits.items():
        assert all(0.85 * card <= chart <= card for chart, card in cards), (width, cards)
    # the row before the gap is a break (no values) 1 ms after the last sample
    assert gap[0] > 6 and gap[1] is None and gap[2] is None and abs(gap[3] - 1e-3) < 1e-6, gap
