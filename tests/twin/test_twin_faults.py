"""Faults in the live path: the incremental detector decides as the offline one, the detector
file round-trips and refuses what it must, the live plant injects faults, and end to end a
faulted plant served over OPC UA raises an alarm with a plausible probable cause."""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from drafttwin._constants import ROLLERS
from drafttwin.diagnosis.detect import FaultDetector
from drafttwin.diagnosis.residuals import block_features
from drafttwin.diagnosis.stream import Step
from drafttwin.errors import ConfigError, DataError
from drafttwin.twin.faultwatch import LiveFaultWatch, load_detector, save_detector
from drafttwin.twin.store.db import SampleRow

from ._twin import cli, env, free_port

RATE = 100.0
ROLLER_RPM = np.array([300.0, 250.0, 100.0, 60.0, 1450.0])


def samples(seed: int, n_s: float, shift: np.ndarray | None = None, at_s: float = 0.0,
            lose: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Measured and predicted speeds (rollers + motor) with AR(1) common-mode level noise per
    block and white sample noise; ``shift`` (relative) from ``at_s``; channel ``lose`` drops
    half its samples in the last 5 s."""
    rng = np.random.default_rng(seed)
    n = int(n_s * RATE)
    t = 1000.0 + np.arange(1, n + 1) / RATE
    common = np.zeros(n)
    for i in range(100, n, 100):  # one AR(1) step per block
        common[i : i + 100] = 0.8 * common[i - 1] + rng.standard_normal() * 6e-5
    rel = common[:, None] * np.array([1, 1, 1, 1, 0.9]) + rng.standard_normal((n, 5)) * 2e-4
    if shift is not None:
        rel[t - t[0] >= at_s] += shift
    yhat = np.tile(ROLLER_RPM, (n, 1))
    y = yhat * (1 + rel)
    if lose is not None:
        y[-500::2, lose] = np.nan
    return t, y, yhat


def rows(t: np.ndarray, y: np.ndarray, yhat: np.ndarray) -> list[SampleRow]:
    nan4 = np.full(4, np.nan)
    return [SampleRow("m", int(round(ti * 1e6)), i, 50.0, yi[:4], yh[:4], nan4, nan4,
                      float(yi[4]), float(yh[4]))
            for i, (ti, yi, yh) in enumerate(zip(t, y, yhat, strict=True))]  # fmt: skip


@pytest.fixture(scope="module")
def detector() -> FaultDetector:
    healthy = [block_features(y, yh, t, 1.0) for t, y, yh in (samples(s, 120) for s in range(3))]
    return FaultDetector(reference_s=10.0).fit(healthy)


def watch_of(detector: FaultDetector | None, **kw: object) -> LiveFaultWatch:
    return LiveFaultWatch(
        "m", ROLLERS, RATE, ROLLER_RPM[1:4] / ROLLER_RPM[0], baseline=detector, **kw
    )  # type: ignore[arg-type]


def fed(watch: LiveFaultWatch, t: np.ndarray, y: np.ndarray, yhat: np.ndarray,
        causes: list[dict[str, object]] | None = None) -> Step:  # fmt: skip
    """Every row into the watch, then the end of the run; a sensor rule's cause as the
    service takes it (at once) into ``causes``."""
    step = Step()
    for r in [*rows(t, y, yhat), None]:
        got = watch.add(r) if r is not None else watch.flush()
        if causes is not None:
            causes += [watch.sensor_cause(a, got) for a in got.alarms if a.direction == 0]
        step += got
    return step


def test_the_live_watch_decides_block_by_block_as_the_offline_detector(detector):
    step = np.array([1, 1, 1, 1, 0]) * -8e-4  # the rollers slow, the motor does not: belt-like
    t, y, yhat = samples(7, 90, shift=step, at_s=40.0, lose=2)
    offline = detector.run(block_features(y, yhat, t, 1.0), stop_at_first=False).alarms
    watch = watch_of(detector, post_s=5)
    causes: list[dict[str, object]] = []
    live = fed(watch, t, y, yhat, causes)

    def key(alarms):  # block times from us stamps (live) and from float times (offline)
        return [(round(a.time_s, 6), a.test, a.direction, round(a.change_s, 6)) for a in alarms]

    cusum = [a for a in offline if a.direction != 0]
    assert cusum and key([a for a in live.alarms if a.direction != 0]) == key(cusum)
    first = live.alarms[0]
    assert first.test == "belt" and first.direction == -1 and 1040 < first.time_s <= 1045
    belt = [r for r in live.requests if r.alarm == first]
    assert len(belt) == 1 and belt[0].n_blocks == 5 and belt[0].sensor is None
    # the shift handed to the ranking is the step (within the block noise)
    assert belt[0].shift[:4] == pytest.approx(step[:4], abs=2e-4)
    assert abs(belt[0].shift[4]) < 2e-4
    sensor = [a for a in live.alarms if a.direction == 0]  # once, where offline lists every block
    assert [a.test for a in offline if a.direction == 0] == ["lost_third"] * 5
    assert [a.test for a in sensor] == ["lost_third"]
    assert [(c["element"], c["kind"]) for c in causes] == [("third", "dropout")]
    assert causes[0]["severity"] == pytest.approx(0.5)


def test_healthy_rows_raise_nothing_and_a_gap_restarts_the_baseline(detector):
    watch = watch_of(detector)
    t, y, yhat = samples(11, 100)
    out = fed(watch, t, y, yhat)
    assert not out.alarms and watch.stream.blocks.finished is False and watch.restarts == 0
    watch = watch_of(detector)
    for r in rows(t, y, yhat):
        watch.add(r)
    assert watch.stream.blocks.blocks == 99  # the last block waits for the rows after it
    later = rows(t + 500.0, y, yhat)  # 400 s of silence: the physics restarted
    watch.add(later[0])
    assert watch.restarts == 1 and watch.stream.decisions is not None
    assert not watch.stream.decisions.state.ready
    with pytest.raises(ConfigError, match="four rollers"):
        LiveFaultWatch("m", ("front", "back"), RATE, np.ones(3), baseline=detector)


def test_a_machine_learns_then_watches_and_a_gap_keeps_its_learning(detector):
    """Without a baseline the machine learns first: no decision, then its own detector (the
    same fit as on its blocks offline), then it watches; a stop in the middle of learning
    makes the next run another record of the same learning."""
    watch = watch_of(None, learn_s=60.0)
    assert watch.learning and watch.learn_left_s == 60.0
    t, y, yhat = samples(12, 40)
    a = fed(watch, t, y, yhat)
    assert watch.learning and not a.alarms and 0.6 < watch.learn_progress < 0.7
    t2, y2, yhat2 = samples(13, 100)
    b = fed(watch, t2 + 100.0, y2, yhat2)  # a new run (a gap of 60 s)
    assert b.learned is not None and not watch.learning and watch.detector is b.learned
    # the learned detector is the one fitted offline on the same blocks: the first run's 40
    # and the second's first 20 (60 s in all)
    off = FaultDetector().fit(
        [block_features(y, yhat, t, 1.0), block_features(y2[:2000], yhat2[:2000], t2[:2000], 1.0)]
    )
    # (the same to rounding: the live block length is 100 periods of 1/100 s)
    assert b.learned.h_ == pytest.approx(off.h_, rel=1e-12)
    assert b.learned.sigma_ == pytest.approx(off.sigma_, rel=1e-9)
    assert b.learned.phi_ == pytest.approx(off.phi_, rel=1e-9)
    assert not b.learned.lags_watched  # 60 s are too few blocks to measure the lags' wander


def test_the_detector_file_round_trips_and_refuses_another_model(detector, tmp_path):
    model = tmp_path / "m.dtm"
    model.write_bytes(b"model bytes")
    path = tmp_path / "m.dtm.detector.json"
    save_detector(path, detector, model, ["a.parquet"], post_s=7.0, machines=["FA320A-SIM-3"])
    back, post, origin = load_detector(path, model)
    assert post == 7.0 and back.h_ == detector.h_ and origin["machines"] == ["FA320A-SIM-3"]
    assert np.array_equal(back.sigma_, detector.sigma_)
    assert np.array_equal(back.level_cov_, detector.level_cov_)
    t, y, yhat = samples(3, 80, shift=np.full(5, -6e-4), at_s=30)
    f = block_features(y, yhat, t, 1.0)
    assert back.run(f).alarms == detector.run(f).alarms != []
    model.write_bytes(b"refitted")
    with pytest.raises(DataError, match="another model"):
        load_detector(path, model)
    doc = json.loads(path.read_text())
    model.write_bytes(b"model bytes")
    for key, value in (("format", "x"), ("post_s", float("nan")), ("post_s", -1),
                       ("machines", "FA320A-SIM-3")):  # fmt: skip
        path.write_text(json.dumps({**doc, key: value}))
        with pytest.raises(DataError):
            load_detector(path, model)
    doc["detector"]["sigma"][0] = -1.0
    path.write_text(json.dumps(doc))
    with pytest.raises(DataError, match="sigma"):
        load_detector(path, model)


def test_the_live_plant_injects_machine_and_sensor_faults():
    from drafttwin.plant.faults import FaultSpec
    from drafttwin.plant.live import LivePlant

    def run(*faults: str) -> np.ndarray:
        p = LivePlant(3, RATE, faults=[FaultSpec.parse(f) for f in faults])
        out = []
        for _ in range(300):
            s = p.step()
            out.append(np.append(s.true_rpm, s.rollers_rpm))
        return np.array(out)

    healthy = run()
    belt = run("main_belt:belt_wear:severity=0.5:onset=1")
    assert np.array_equal(belt[:90], healthy[:90])  # nothing before the onset
    slip = belt[200:, :4].mean(axis=0) / healthy[200:, :4].mean(axis=0) - 1
    assert np.all((slip < -3e-4) & (slip > -3e-3))  # the creep grows: every roller slower
    gain = run("third:gain:severity=0.01:onset=1")
    assert np.array_equal(gain[:, :4], healthy[:, :4])  # the truth is untouched
    ratio = np.nanmean(gain[200:, 6]) / np.nanmean(healthy[200:, 6])
    assert ratio == pytest.approx(1.01, abs=5e-4)
    with pytest.raises(ConfigError, match="live plant"):
        LivePlant(3, RATE, faults=[FaultSpec.parse("motor:rotor_resistance:severity=0.1:onset=1")])
    with pytest.raises(ConfigError, match="full physics"):
        LivePlant(3, RATE, physics="reduced",
                  faults=[FaultSpec.parse("main_belt:belt_wear:severity=0.5:onset=1")])  # fmt: skip


def test_cli_refuses_bad_fault_and_detector_input(twin_files, tmp_path):
    record, model = twin_files
    code, _, err = invoke("plant", "serve", "--opcua", "opc.tcp://127.0.0.1:1", "--duration",
                       "0.1", "--fault", "nowhere:belt_wear:severity=0.5:onset=1")  # fmt: skip
    assert code == 2 and "nowhere" in err and "--fault" in err
    code, _, err = invoke("plant", "serve", "--opcua", "opc.tcp://127.0.0.1:1", "--duration",
                       "0.1", "--fault", "motor:rotor_resistance:severity=0.1:onset=1")  # fmt: skip
    assert code == 2 and "cannot be injected into the live plant" in err
    replay = f"replay:{record}?speed=inf"
    code, _, err = invoke("twin", "run", "--model", str(model), "--source", replay,
                       "--detector", str(tmp_path / "none.json"))  # fmt: skip
    assert code == 2 and "--detector" in err and "no detector file" in err
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    code, _, err = invoke("twin", "run", "--model", str(model), "--source", replay,
                       "--detector", str(bad))  # fmt: skip
    assert code == 2 and "not a drafttwin live detector" in err
    code, _, err = invoke("twin", "fit-detector", "--model", str(model), "--healthy", str(record))
    assert code == 2 and "longer" in err  # 6 s is not longer than the 15-s baseline
    assert not (tmp_path / "tiny.dtm.detector.json").exists()


def invoke(*args: str) -> tuple[int, str, str]:
    """The CLI in this process (no interpreter start-up): exit code, stdout, stderr."""
    from typer.testing import CliRunner

    from drafttwin.cli import app

    res = CliRunner().invoke(app, list(args))
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    return res.exit_code, res.stdout, res.stderr


@pytest.mark.slow
def test_a_faulted_plant_served_live_raises_an_alarm_naming_the_belt(tmp_path, twin_files):
    """Thresholds from two healthy records; the plant served over OPC UA with a belt wearing
    from 9 s; the twin's store names the belt; a healthy replay raises nothing."""
    from drafttwin.plant import Plant

    _, model_src = twin_files
    model = tmp_path / "m.dtm"
    model.write_bytes(model_src.read_bytes())
    healthy = []
    for seed in (1, 2):
        healthy.append(tmp_path / f"h{seed}.parquet")
        Plant().run(10.0, 100.0, seed=seed).write(healthy[-1])
    code, _, err = invoke("twin", "fit-detector", "--model", str(model), "--healthy",
                          ",".join(map(str, healthy)), "--reference", "3", "--post", "3")  # fmt: skip
    assert code == 0, err
    port = free_port()
    plant = subprocess.Popen(cli("plant", "serve", "--opcua", f"opc.tcp://127.0.0.1:{port}",
                                 "--duration", "23", "--seed", "5",
                                 "--fault", "main_belt:belt_wear:severity=0.6:onset=9"),
                             env=env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                             text=True)  # fmt: skip
    try:
        assert plant.stderr is not None and "serving" in plant.stderr.readline()
        # --learn 0: the detector file judges the machine as it is (no learning state); it
        # was fitted on other machines (seeds 1 and 2) and the twin says so by name
        code, out, err = invoke("twin", "run", "--model", str(model), "--source",
                                f"opcua:opc.tcp://127.0.0.1:{port}", "--store",
                                str(tmp_path / "st"), "--duration", "14", "--learn", "0",
                                "--quiet", "--json")  # fmt: skip
    finally:
        plant.kill()
        plant.wait()
    assert code == 0, err
    assert json.loads(out)["machines"]["fa320a"]["fault_detector"] is True
    import duckdb

    con = duckdb.connect(str(tmp_path / "st" / "twin.duckdb"), read_only=True)
    # machine-fault alarms only: thresholds from recorded-plant records can raise a 'stuck'
    # sensor alarm on the live plant, whose steadier speeds repeat encoder values longer
    # (docs/twin.md; fit on a 'plant serve --log' to avoid it)
    events = con.execute("SELECT kind, detail FROM events WHERE kind IN ('fault', 'fault-cause') "
                         "ORDER BY ts_us, kind").fetchall()  # fmt: skip
    foreign = con.execute("SELECT detail FROM events WHERE kind = 'detector-foreign'").fetchall()
    con.close()
    assert len(foreign) == 1 and "FA320A-SIM-1, FA320A-SIM-2" in foreign[0][0], foreign
    assert "not on this machine (serial FA320A-SIM-5)" in foreign[0][0]
    assert [k for k, _ in events][:2] == ["fault", "fault-cause"], events
    cause = json.loads(events[1][1])
    top = cause["causes"][0]
    assert "main_belt:belt_wear" in [f"{top['element']}:{top['kind']}", *top["group"]], cause
    # healthy: a healthy record replayed raises nothing
    code, out, err = invoke("twin", "run", "--model", str(model), "--source",
                            f"replay:{healthy[0]}?speed=inf", "--learn", "0", "--quiet",
                            "--json")  # fmt: skip
    assert code == 0, err
    assert json.loads(out)["machines"]["h1"]["fault_alarms"] == 0


def test_the_hall_page_shows_every_shard_and_guards_its_token():
    import urllib.error
    import urllib.request

    from drafttwin.twin.web.hall import HallServer, HallView

    def get(url: str, headers: dict[str, str] | None = None) -> tuple[int, str]:
        req = urllib.request.Request(url, headers=headers or {})
        try:
            with urllib.request.urlopen(req, timeout=10) as r:  # noqa: S310  a local test server
                return r.status, r.read().decode()
        except urllib.error.HTTPError as exc:
            return exc.code, ""

    view = HallView(2)
    fault = {"kind": "fault-cause", "time": 5.0, "test": "belt", "causes": [
        {"element": "main_belt", "kind": "belt_wear", "severity": 0.5, "probability": 0.9}]}  # fmt: skip
    machine = {"state": "live", "received": 10, "processed": 10, "dropped": 0,
               "fault_alarms": 1, "fault_detector": True, "last_fault": fault, "source": "x"}  # fmt: skip
    view.update([{"rows": 10, "latency_ms": {"p99": 1.5, "p50": 1.0, "max": 2.0},
                  "machines": {"m-1": machine}}, None])  # fmt: skip
    token, port = "t" * 20, free_port()
    base = f"http://127.0.0.1:{port}"
    with HallServer(view, ("127.0.0.1", port), token):
        assert get(f"{base}/api/hall")[0] == 401
        code, text = get(f"{base}/api/hall?token={token}")
        page = get(f"{base}/", {"Authorization": f"Bearer {token}"})
    hall = json.loads(text)
    assert code == 200 and [s["state"] for s in hall["shards"]] == ["running", "starting"]
    m = hall["shards"][0]["machines"]["m-1"]
    assert m["last_fault"]["causes"][0]["element"] == "main_belt" and "source" not in m
    assert page[0] == 200 and "api/hall" in page[1]


def test_a_plant_log_gives_one_healthy_record_per_machine(tmp_path, twin_files):
    from drafttwin.plant.live import LivePlant
    from drafttwin.twin.faultwatch import plant_log_series
    from drafttwin.wire.plantlog import open_plant_log

    path = tmp_path / "log.parquet"
    plants = {"a": LivePlant(1, RATE), "b": LivePlant(2, RATE)}
    with open_plant_log(path) as log:
        assert log is not None
        for _ in range(150):
            for name, p in plants.items():
                log.add(name, p.step())
    records = plant_log_series(path)
    assert records is not None and len(records) == 2
    a = records[0]
    assert len(a.time_s) == 150 and a.time_s[1] == pytest.approx(0.01)
    assert a.motor_rpm is not None and np.nanmedian(a.motor_rpm) > 1000
    assert a.inputs["supply_hz"][0] == pytest.approx(48.47, abs=1.0)
    assert plant_log_series(twin_files[0]) is None  # a recorded file is not a log


def test_machines_close_their_blocks_on_different_samples(detector):
    from drafttwin.twin.faultwatch import block_phase

    phases = [block_phase(f"df-{i:02d}", RATE, 1.0) for i in range(20)]
    assert all(0 <= p < 100 for p in phases) and len(set(phases)) > 12
    watch = watch_of(detector, phase=37)
    t, y, yhat = samples(4, 3.5)
    for r in rows(t, y, yhat):
        watch.add(r)
    # rows 0-36 left out; blocks end on rows 136, 236 and 336, each final once the next one
    # closed (its lags anchor on the rows after it)
    assert watch.stream.blocks.blocks == 2 and watch.stream.decisions is not None
    assert watch.stream.decisions.times == [pytest.approx(t[136]), pytest.approx(t[236])]
    watch.flush()


def test_a_sensor_rule_in_the_window_takes_the_machine_ranking_over(detector):
    """The back encoder freezes on a wrong value (0.9 % high) for about 1 s: a test of the
    back roller alarms on the 25 held samples at a block's end, the stuck rule (limit 30
    samples, as long healthy tuning records give it) a block later. The live watch names the
    encoder and its window sizes it on the samples (as offline): no machine ranking; after
    the episode a new baseline takes up the counted angle the held values moved: no lag alarm."""
    import copy

    detector = copy.copy(detector)
    detector.run_limit_ = detector.stale_limit_ = np.full(5, 30.0)
    t, y, yhat = samples(5, 60)
    y[3175:3300, 3] = y[3174, 3] * 1.009
    watch = watch_of(detector, post_s=5)
    causes: list[dict[str, object]] = []
    step = fed(watch, t, y, yhat, causes)
    alarms = step.alarms
    # the held samples move the back roller's level and its counted angle: its parity or its
    # lag (the jump rule) alarms first, whichever crosses first
    assert [a.test for a in alarms] in (["parity_back", "stuck_back"], ["lag_back", "stuck_back"])
    assert alarms[1].block == alarms[0].block + 1
    assert causes and causes[0]["element"] == "back" and causes[0]["kind"] == "stuck"
    # in seconds, the unit a stuck encoder is injected with: the held run the rule counted
    # (over 30 samples, at most the 125 held) at RATE
    assert 30 / RATE < causes[0]["severity"] <= 125 / RATE and "(s" in causes[0]["parameter"]
    # one window, the machine alarm's, taken over by the encoder: sized on the samples
    assert len(step.requests) == 1 and step.requests[0].alarm == alarms[0]
    req = step.requests[0]
    assert req.sensor == ("back", "stuck") and req.raw_y is not None
    from drafttwin.diagnosis.diagnose import Diagnoser
    from drafttwin.mechanics import DriveTrain

    _, (cause,) = Diagnoser(DriveTrain.preset("fa320a"), detector).locate(req)
    assert cause.name == "back:stuck" and cause.severity == pytest.approx(1.25, abs=0.011)


def test_a_sensor_alarm_after_learning_is_named_with_its_block():
    """A machine that learned first counts its decided blocks from the learning's end, its
    block stream from the start: a sensor alarm after learning must still find the block that
    raised it (a KeyError in the twin's loop before: every live sensor alarm after learning
    lost its event and its cause)."""
    watch = watch_of(None, learn_s=60.0, post_s=5)
    t, y, yhat = samples(14, 120)
    y[9175:9300, 3] = y[9174, 3] * 1.009  # the back encoder holds a value 0.9 % high
    causes: list[dict[str, object]] = []
    step = fed(watch, t, y, yhat, causes)
    assert step.learned is not None
    sensor = [a for a in step.alarms if a.direction == 0]
    assert [a.test for a in sensor] == ["stuck_back"]
    assert [(c["element"], c["kind"]) for c in causes] == [("back", "stuck")]
    assert (
        sensor[0].block in step.blocks and step.blocks[sensor[0].block].time_s == sensor[0].time_s
    )


def test_the_locator_worker_ends_with_a_twin_killed_outright(tmp_path: Path) -> None:
    """The ranking worker process watches its twin: a twin killed by SIGKILL (no cleanup at
    all) leaves no worker behind (orphans of 290 MB each piled up before)."""
    import os
    import sys

    code = (
        "import os, time\n"
        "from drafttwin.twin.faultwatch import Locator\n"
        "loc = Locator()\n"
        "print(loc._executor().submit(os.getpid).result(), flush=True)\n"
        "time.sleep(60)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    worker = int(proc.stdout.readline())
    assert Path(f"/proc/{worker}").exists() or not sys.platform.startswith("linux")
    proc.kill()
    proc.wait(timeout=30)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        try:
            os.kill(worker, 0)
        except ProcessLookupError:
            return
        time.sleep(0.1)
    raise AssertionError(f"the worker {worker} outlived its killed twin")


def test_an_active_alarm_returns_to_normal_in_the_run_after_a_gap(detector):
    """A belt replaced during a stop: the rows after the gap are a new run (a new reference
    window), whose return-to-normal watch had started empty: the alarm stayed active until
    the machine was learnt again."""
    step = np.array([1, 1, 1, 1, 0]) * -8e-4
    t, y, yhat = samples(21, 90, shift=step, at_s=40.0)
    watch = watch_of(detector)
    before = Step()
    for r in rows(t, y, yhat):
        before += watch.add(r)
    belt = [a for a in before.alarms if a.test == "belt"]
    assert belt and not before.cleared
    t2, y2, yhat2 = samples(23, 80)  # healthy again, after five minutes of standstill
    after = Step()
    for r in rows(t2 + 400.0, y2, yhat2):
        after += watch.add(r)
    assert watch.restarts == 1 and after.cleared == belt[:1] and not after.alarms
