"""The plant's own log ('plant serve --log') and 'twin audit': a store counted sample by
sample against what the plant published; and kill -9 of a live OPC UA twin counted that way."""

from __future__ import annotations

import json
import random
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from drafttwin.cli import app
from drafttwin.plant.live import LiveSample
from drafttwin.twin.store.audit import audit
from drafttwin.twin.store.db import SampleRow, TwinStore
from drafttwin.twin.store.history import read_events
from drafttwin.wire.plantlog import PlantLog, read_plant_log

from ._twin import CHANNELS, cli, env, free_port

pytestmark = pytest.mark.timeout(180)


def _sample(seq: int, rng: np.random.Generator) -> LiveSample:
    rollers = rng.normal(500.0, 50.0, 4)
    if seq % 7 == 0:
        rollers[:] = np.nan  # a dropped logger row is published (and logged) as NaN
    return LiveSample(seq, 1000.0 + seq / 100, rollers, 1450.0, 48.47, rollers)


@pytest.mark.parametrize("suffix", [".parquet", ".csv"])
def test_plant_log_round_trip_and_audit_counts(tmp_path: Path, suffix: str) -> None:
    rng = np.random.default_rng(3)
    samples = [_sample(k, rng) for k in range(1, 3001)]  # 3000: more than one row group
    path = tmp_path / f"plant{suffix}"
    with PlantLog(path) as log:
        for s in samples:
            log.add("m1", s)
        assert not path.exists()  # appears whole when the plant stops
    frame = read_plant_log(path)
    assert len(frame) == 3000 and frame["seq"].tolist() == list(range(1, 3001))
    np.testing.assert_array_equal(frame["front"], [s.rollers_rpm[0] for s in samples])
    assert (frame["ts_us"] == np.round((1000.0 + frame["seq"] / 100) * 1e6)).all()
    # a store that lacks 1-10 (start-up), 101-150 and 2991-3000, stores seq 200 with another
    # value, and holds a made-up row (seq -1) for 151
    store = TwinStore(tmp_path / "store")
    store.register_machine("m1", CHANNELS, "x", "test")
    keep = [s for s in samples if 10 < s.seq <= 100 or 150 < s.seq <= 2990]
    rows = [SampleRow("m1", int(round(s.time_s * 1e6)), s.seq, 48.47, s.rollers_rpm.copy(),
                      s.rollers_rpm, s.rollers_rpm, s.rollers_rpm * 0) for s in keep]  # fmt: skip
    rows[[r.seq for r in rows].index(200)].measured[1] += 0.5
    rows[[r.seq for r in rows].index(151)].ts_us += 1
    made_up = int(round((1000 + 101 / 100) * 1e6))  # a row for a sample never received
    rows.append(SampleRow("m1", made_up, -1, 48.47, *(np.full(4, np.nan),) * 4))
    store.commit(rows, [])
    store.close()
    (m,) = audit(tmp_path / "store", path)
    assert (m.published, m.stored, m.duplicates, m.foreign, m.filled) == (3000, 2930, 0, 0, 1)
    assert m.mismatched == 2  # seq 200's value, seq 151's time
    assert (m.before_first, m.after_last, m.missing_inside) == (10, 10, 50)
    (run,) = m.runs
    assert (run.first_seq, run.last_seq, run.samples) == (101, 150, 50)
    assert run.first_time_s == pytest.approx(1001.01)
    res = CliRunner().invoke(app, ["twin", "audit", "--store", str(tmp_path / "store"),
                                   "--plant-log", str(path), "--json"])  # fmt: skip
    assert res.exit_code == 0, res.stderr
    assert json.loads(res.stdout)["machines"][0]["runs"][0]["samples"] == 50


def _error(res, *needles: str) -> None:  # noqa: ANN001
    assert res.exit_code == 2, res.stdout + res.stderr
    assert res.stderr.startswith("error:") and "Traceback" not in res.stderr
    for n in needles:
        assert n in res.stderr, res.stderr


def test_bad_logs_and_broker_modes_are_refused(tmp_path: Path) -> None:
    run = CliRunner().invoke
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    _error(run(app, ["plant", "serve", "--opcua", url, "--log", str(tmp_path / "x.txt")]),
           "--log", "*.parquet or *.csv")  # fmt: skip
    _error(run(app, ["plant", "serve", "--opcua", url, "--broker", "mosquitto"]), "--broker")
    _error(run(app, ["plant", "serve", "--mqtt", f"127.0.0.1:{free_port()}", "--broker",
                     "external", "--log", str(tmp_path / "p.parquet")]),
           "no MQTT broker answers", "--broker external")  # fmt: skip
    assert not list(tmp_path.iterdir())  # no log, not even a temporary file
    other = tmp_path / "other.parquet"
    pd.DataFrame({"machine": ["m"], "seq": [1.5]}).to_parquet(other)
    store = TwinStore(tmp_path / "store")
    store.close()
    _error(run(app, ["twin", "audit", "--store", str(tmp_path / "store"), "--plant-log",
                     str(other)]), "not a plant log")  # fmt: skip


def _commits(proc: subprocess.Popen[str], n: int, timeout: float) -> list[dict[str, float]]:
    """Read ``n`` commit lines of 'twin run --verbose' (rows, last_ts_us, ms, at)."""
    out: list[dict[str, float]] = []
    deadline = time.monotonic() + timeout
    assert proc.stdout is not None
    while len(out) < n and time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        if line.startswith("commit "):
            out.append({k: float(v) for k, v in (f.split("=") for f in line.split()[1:])})
    assert len(out) == n, (proc.stderr.read() if proc.stderr else "") + f" ({len(out)} commits)"
    return out


def _stop(proc: subprocess.Popen[str], sig: int = signal.SIGTERM) -> None:
    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=30)


@pytest.mark.slow  # a plant and two twin start-ups: about 35 s each
@pytest.mark.parametrize(
    "history_s",
    [pytest.param(0, marks=pytest.mark.long), 60],  # the suite keeps the server-history variant
    ids=["no-history", "server-history"],
)
def test_kill_9_of_a_live_twin_counted_against_the_plant_log(
    tmp_path: Path, twin_files: tuple[Path, Path], history_s: int
) -> None:
    """Without server history the store lacks the samples of the open commit interval (the
    bound) and those published while no twin ran (the restart gap, reported apart); with
    it, the restarted twin reads both back from the server and the store lacks nothing."""
    _, model = twin_files
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    plant_log, store = tmp_path / "plant.parquet", tmp_path / "store"
    plant = subprocess.Popen(cli("plant", "serve", "--opcua", url, "--physics", "reduced",
                                 "--log", str(plant_log), "--history", str(history_s)), env=env(),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    twin_args = ["twin", "run", "--model", str(model), "--source", f"opcua:{url}", "--store",
                 str(store), "--commit-ms", "100", "--verbose", "--quiet"]  # fmt: skip
    procs = [plant]
    try:
        assert plant.stderr is not None
        assert "serving fa320a" in plant.stderr.readline()
        first = subprocess.Popen(cli(*twin_args), env=env(), stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True)  # fmt: skip
        procs.append(first)
        acked = _commits(first, 8, 90)
        time.sleep(random.Random(7).uniform(0.0, 0.1))  # anywhere in a commit interval
        first.send_signal(signal.SIGKILL)
        killed_at = time.time()
        first.wait(timeout=30)
        second = subprocess.Popen(cli(*twin_args), env=env(), stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True)  # fmt: skip
        procs.append(second)
        resumed = _commits(second, 10, 90)
        _stop(plant)  # SIGTERM: the plant writes its log
        time.sleep(1.0)  # the twin receives what is in flight, then it is stopped the same way
        _stop(second)
        assert second.returncode == 0, second.stderr.read() if second.stderr else ""
    finally:
        for p in procs:
            _stop(p, signal.SIGKILL)
    (m,) = audit(store, plant_log)
    log = read_plant_log(plant_log)
    # nothing stored twice, nothing stored different from what the plant published, no row
    # made up: OPC UA delivered every sample to a running twin
    assert (m.duplicates, m.mismatched, m.foreign, m.filled) == (0, 0, 0, 0)
    # a twin stopped by SIGTERM commits what it received; what it lacks at the end is what the
    # stopping server had not sent yet: its last publishing intervals (10 ms each; a loaded
    # server's publishing task lags its writes)
    tail = log[log["seq"] > log["seq"].max() - m.after_last]
    assert (tail["published"] > log["published"].max() - 0.25).all(), m.after_last
    if history_s:  # the restarted twin recovered the open interval and the restart gap
        assert (m.missing_inside, m.runs) == (0, [])
        recovered = read_events(store).query("kind == 'history'")["detail"].tolist()
        assert len(recovered) == 1 and "samples recovered" in recovered[0]
        print(
            f"kill -9 with server history: {recovered[0]}, stored {m.stored} of {m.published}, after the last {m.after_last}"
        )  # noqa: T201
        return
    (run,) = m.runs  # one hole: the kill and the restart
    assert run.first_time_s * 1e6 > acked[-1]["last_ts_us"]  # every acknowledged row is there
    hole = log[(log["seq"] >= run.first_seq) & (log["seq"] <= run.last_seq)]
    lost = int((hole["published"] <= killed_at).sum())  # received (or in flight), not committed
    gap = len(hole) - lost  # published while no twin ran
    # the stated bound: one commit interval plus the commit's own time, plus the transport
    # (an OPC UA publish every 10 ms) and the reorder buffer (3 samples)
    bound_s = 0.1 + max(c["ms"] for c in acked) / 1e3 + 0.05
    assert lost <= bound_s * 100, (lost, bound_s)
    assert run.last_published_s < resumed[0]["at"]  # the restart gap ends with the new twin
    print(
        f"kill -9: lost {lost} samples ({lost * 10} ms, bound {bound_s * 1e3:.0f} ms), "
        f"restart gap {gap} samples, stored {m.stored} of {m.published}, before the first "
        f"{m.before_first}, after the last {m.after_last}"
    )  # noqa: T201


def test_a_restarted_plants_other_run_is_counted_apart(tmp_path: Path) -> None:
    # a plant restarted counts from 0 again: the store's rows of the other run had read as
    # 2009 stored twice and 2264 differing; a log of another run entirely: refused
    from dataclasses import replace

    from drafttwin.errors import DataError

    rng = np.random.default_rng(3)
    first = [_sample(k, rng) for k in range(1, 501)]  # 1000.01-1005.00 s
    second = [replace(_sample(k, rng), time_s=2000.0 + k / 100) for k in range(1, 401)]
    logs = []
    for i, run in enumerate((first, second)):
        logs.append(tmp_path / f"plant{i}.parquet")
        with PlantLog(logs[-1]) as log:
            for s in run:
                log.add("m1", s)
    store = TwinStore(tmp_path / "store")
    store.register_machine("m1", CHANNELS, "x", "test")
    store.commit([SampleRow("m1", int(round(s.time_s * 1e6)), s.seq, 48.47, s.rollers_rpm.copy(),
                            s.rollers_rpm, s.rollers_rpm, s.rollers_rpm * 0)
                  for s in (*first, *second)], [])  # fmt: skip
    store.close()
    for log_path, (published, outside) in zip(logs, ((500, 400), (400, 500)), strict=True):
        (m,) = audit(tmp_path / "store", log_path)
        assert (m.published, m.stored, m.duplicates, m.mismatched) == (published, published, 0, 0)
        assert m.outside == outside and m.missing_inside == 0
    # both runs' logs at once: each counted within its own span, nothing outside
    both = audit(tmp_path / "store", logs)
    assert [(m.log, m.published, m.stored, m.outside) for m in both] == [
        (str(logs[0]), 500, 500, 0), (str(logs[1]), 400, 400, 0)]  # fmt: skip
    res = CliRunner().invoke(app, ["twin", "audit", "--store", str(tmp_path / "store"),
                                   "--plant-log", f"{logs[0]},{logs[1]}"])  # fmt: skip
    assert res.exit_code == 0, res.stderr
    assert "plant0.parquet" in res.stdout and "plant1.parquet" in res.stdout
    with pytest.raises(DataError, match="given twice"):
        audit(tmp_path / "store", [logs[0], logs[0]])
    copy = tmp_path / "copy.parquet"
    copy.write_bytes(logs[0].read_bytes())
    with pytest.raises(DataError, match="both log machine 'm1' over the same time"):
        audit(tmp_path / "store", [logs[0], copy])
    other = tmp_path / "other.parquet"
    with PlantLog(other) as log:
        log.add("m1", replace(_sample(1, rng), time_s=9000.0))
    with pytest.raises(DataError, match="no sample of this log's time span"):
        audit(tmp_path / "store", other)
