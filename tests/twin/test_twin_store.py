"""The twin's DuckDB store: round trip, no duplicates, retention, refusals, and kill -9."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import duckdb
import numpy as np
import pytest

from drafttwin.errors import ConfigError, DataError
from drafttwin.twin.store.db import EventRow, SampleRow, StoreWriter, TwinStore, store_path
from drafttwin.twin.store.history import read_events, read_history

from ._twin import CHANNELS, cli, env, read_plant, run_cli

pytestmark = pytest.mark.timeout(180)


def _rows(machine: str, start: int, n: int) -> list[SampleRow]:
    rng = np.random.default_rng(start)
    return [SampleRow(machine, (start + i) * 10_000, start + i, 48.0 + i * 1e-3,
                      *(rng.normal(400, 50, 4) for _ in range(4)))
            for i in range(n)]  # fmt: skip


def test_rows_round_trip_and_duplicates_are_dropped(tmp_path: Path) -> None:
    store = TwinStore(tmp_path)
    store.register_machine("m1", CHANNELS, "model.dtm", "test")
    rows = _rows("m1", 0, 50)
    store.commit(rows[:30], [EventRow("m1", "gap", 5, "3 samples")])
    store.commit(rows[20:], [EventRow("m1", "gap", 5, "again")])  # 10 rows and 1 event again
    assert store.last_ts_us("m1") == 49 * 10_000
    store.close()
    frame = read_history(tmp_path)
    assert len(frame) == 50 and frame["time"].is_unique
    np.testing.assert_array_equal(frame["front"], [r.measured[0] for r in rows])
    np.testing.assert_array_equal(frame["back_residual"], [r.residual[3] for r in rows])
    np.testing.assert_array_equal(frame["third_twin"], [r.twin[2] for r in rows])
    window = read_history(tmp_path, "m1", 0.1, 0.2)
    assert window["time"].tolist() == pytest.approx(np.arange(10, 21) / 100)
    events = read_events(tmp_path)
    assert events["detail"].tolist() == ["3 samples"]


def test_retention_keeps_the_newest_span_per_machine(tmp_path: Path) -> None:
    store = TwinStore(tmp_path)
    for m in ("a", "b"):
        store.register_machine(m, CHANNELS, "x", "test")
    store.commit(_rows("a", 0, 300) + _rows("b", 1000, 100), [])
    deleted = store.apply_retention(keep_s=1.0)  # 1 s = 100 samples before each newest
    store.close()
    frame = read_history(tmp_path)
    counts = frame.groupby("machine").size().to_dict()
    assert counts == {"a": 101, "b": 100}
    assert deleted == 199


def test_writer_commits_in_batches_and_bounds_its_queue(tmp_path: Path) -> None:
    store = TwinStore(tmp_path)
    store.register_machine("m1", CHANNELS, "x", "test")
    writer = StoreWriter(store, commit_ms=20, max_pending=10**6)
    for row in _rows("m1", 0, 200):
        writer.put(row)
    time.sleep(0.3)
    assert writer.committed == 200  # committed by the thread while we waited
    writer.max_pending = 0
    writer.put(_rows("m1", 500, 1)[0])
    assert writer.dropped == 1
    writer.close()
    store.close()


def test_foreign_files_and_channel_changes_are_refused(tmp_path: Path) -> None:
    con = duckdb.connect(str(store_path(tmp_path)))
    con.execute("CREATE TABLE x (a INT)")
    con.close()
    with pytest.raises(DataError, match="not a drafttwin twin store"):
        TwinStore(tmp_path)
    other = tmp_path / "other"
    store = TwinStore(other)
    store.register_machine("m1", CHANNELS, "x", "test")
    with pytest.raises(DataError, match="was stored with channels"):
        store.register_machine("m1", ("front", "back"), "x", "test")
    store.close()
    with pytest.raises(DataError, match="no twin store here"):
        read_history(tmp_path / "nowhere")


def test_a_store_whose_creation_was_killed_is_made_again(tmp_path: Path) -> None:
    """The schema and the format record are one transaction: a kill -9 while a store is made
    leaves a database with no table (made again on the next open), never a half store."""
    duckdb.connect(str(store_path(tmp_path))).close()  # what such a kill leaves
    store = TwinStore(tmp_path)
    store.register_machine("m1", CHANNELS, "x", "test")
    store.commit(_rows("m1", 0, 3), [])
    store.close()
    assert len(read_history(tmp_path)) == 3


@pytest.mark.slow  # two CLI start-ups and a live replay: about 30 s
def test_kill_9_loses_nothing_committed_and_a_restart_duplicates_nothing(
    tmp_path: Path, twin_files: tuple[Path, Path]
) -> None:
    record, model = twin_files
    plant = read_plant(record)
    store = tmp_path / "store"
    args = ["twin", "run", "--model", str(model), "--source", f"replay:{record}?speed=1.5",
            "--store", str(store), "--commit-ms", "100", "--verbose"]  # fmt: skip
    proc = subprocess.Popen(cli(*args), env=env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)  # fmt: skip
    acked: list[int] = []
    try:
        deadline = time.monotonic() + 90
        assert proc.stdout is not None
        while len(acked) < 8 and time.monotonic() < deadline:
            line = proc.stdout.readline()
            if line.startswith("commit "):
                acked.append(int(line.split("last_ts_us=")[1]))
        assert len(acked) == 8, proc.stderr.read() if proc.stderr else ""
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    frame = read_history(store)
    ts = np.round(frame["time"].to_numpy() * 1e6).astype(np.int64)
    # every acknowledged commit survived, and what is stored is the file's first rows, whole
    assert ts[-1] >= acked[-1]
    np.testing.assert_array_equal(ts, plant["ts_us"].to_numpy()[: len(ts)])
    assert len(ts) < len(plant)  # killed mid-way
    # restart: resumes after the stored rows; in the end every row once
    done = run_cli(*args, "--json")
    assert done.returncode == 0, done.stderr
    final = read_history(store)
    np.testing.assert_array_equal(np.round(final["time"].to_numpy() * 1e6).astype(np.int64),
                                  plant["ts_us"].to_numpy())  # fmt: skip
    np.testing.assert_array_equal(final["front"].to_numpy(), plant["front"].to_numpy())


def test_query_while_a_twin_holds_the_store_says_so(tmp_path: Path) -> None:
    store = TwinStore(tmp_path)
    store.register_machine("m1", CHANNELS, "x", "test")
    store.close()
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, duckdb; con = duckdb.connect(sys.argv[1]); "
         "print('open', flush=True); sys.stdin.read()", str(store_path(tmp_path))],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "open"
        res = run_cli("twin", "query", "--store", str(tmp_path), timeout=60)
    finally:
        holder.kill()
        holder.wait(timeout=30)
    assert res.returncode == 2
    assert "the store is in use by a running twin" in res.stderr
    assert "Traceback" not in res.stderr


def test_a_hall_folder_is_not_opened_as_one_twins_store(tmp_path: Path) -> None:
    # a store beside a hall's shards would hide them from 'twin query' and 'twin audit'
    TwinStore(tmp_path / "shard-0-of-2").close()
    with pytest.raises(ConfigError, match="holds the stores of a hall's shards"):
        TwinStore(tmp_path)
    assert not (tmp_path / "twin.duckdb").exists()


def test_events_are_read_within_the_window(tmp_path: Path) -> None:
    """``twin query --events --from --to`` had returned every event of the store."""
    from typer.testing import CliRunner

    from drafttwin.cli import app

    store = TwinStore(tmp_path / "s")
    store.register_machine("m1", CHANNELS, "model.dtm", "test")
    store.commit(_rows("m1", 0, 10), [EventRow("m1", "gap", t * 1_000_000, f"at {t} s")
                                      for t in (1, 5, 9)])  # fmt: skip
    store.close()
    assert read_events(tmp_path / "s", None, 4.0, 9.0)["detail"].tolist() == ["at 5 s", "at 9 s"]
    assert read_events(tmp_path / "s", "m1", None, 4.0)["detail"].tolist() == ["at 1 s"]
    out = tmp_path / "ev.csv"
    res = CliRunner().invoke(app, ["twin", "query", "--store", str(tmp_path / "s"), "--events",
                                   "--from", "2", "--to", "6", "--out", str(out)])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "1 events selected" in res.output
