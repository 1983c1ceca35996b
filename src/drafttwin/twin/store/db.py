"""The twin's history: one DuckDB file, written in batch commits by one writer thread.

Why DuckDB (docs/twin.md): one file, one transaction per batch (a crash keeps every
committed batch whole and nothing of the open one: the write-ahead log is replayed on the
next open), a primary key that refuses duplicates, and columnar analytics for the history
queries. Its one limit: a single process holds the file, so ``drafttwin twin query`` reads a
store while no twin runs on it (a running twin serves its history over HTTP instead).

Tables:

* ``samples``: one row per machine and sample time: ``seq`` (the source's counter), the
  set-point, and per output channel (lists in the machine's channel order) the measured,
  physics, twin and residual values. Primary key ``(machine, ts_us)``.
* ``events``: gaps, reconnects, dropped payloads, alarms. Primary key ``(machine, kind, ts_us)``.
* ``machines``: each machine's channels, model file and source.
* ``meta``: the store's format version (checked on open).

Loss bound: rows are committed every ``commit_ms``; ``kill -9`` loses the rows received since
the last commit (at most one interval plus the commit's own time). A restart resumes after
:meth:`TwinStore.last_ts_us` and ``INSERT OR IGNORE`` drops whatever a source sends again.
"""

from __future__ import annotations

import contextlib
import math
import queue
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drafttwin.errors import ConfigError, DataError

STORE_FILE = "twin.duckdb"
FORMAT = "drafttwin-twin-store"
VERSION = 1
KINDS = ("measured", "physics", "twin", "residual")
"""Per-channel value lists of a sample row, in this order."""

_SCHEMA = (
    "CREATE TABLE IF NOT EXISTS meta (key VARCHAR PRIMARY KEY, value VARCHAR)",
    "CREATE TABLE IF NOT EXISTS machines (machine VARCHAR PRIMARY KEY, channels VARCHAR[], "
    "model VARCHAR, source VARCHAR)",
    "CREATE TABLE IF NOT EXISTS samples (machine VARCHAR NOT NULL, ts_us BIGINT NOT NULL, "
    "seq BIGINT, setpoint DOUBLE, measured DOUBLE[], physics DOUBLE[], twin DOUBLE[], "
    "residual DOUBLE[], PRIMARY KEY (machine, ts_us))",
    "CREATE TABLE IF NOT EXISTS events (machine VARCHAR NOT NULL, kind VARCHAR NOT NULL, "
    "ts_us BIGINT NOT NULL, detail VARCHAR, PRIMARY KEY (machine, kind, ts_us))",
)


@dataclass
class SampleRow:
    """One processed sample of one machine (values per channel, NaN = none)."""

    machine: str
    ts_us: int
    seq: int
    setpoint: float
    measured: np.ndarray
    physics: np.ndarray
    twin: np.ndarray
    residual: np.ndarray
    motor: float = math.nan  # measured motor speed, rpm (the fault detector's; not stored)
    motor_physics: float = math.nan  # the physics' motor speed, rpm


@dataclass
class EventRow:
    machine: str
    kind: str
    ts_us: int
    detail: str


def store_path(folder: str | Path) -> Path:
    return Path(folder) / STORE_FILE


def _connect(path: Path, *, read_only: bool) -> Any:
    import duckdb

    try:
        return duckdb.connect(str(path), read_only=read_only)
    except duckdb.IOException as exc:
        text = str(exc)
        if "lock" in text.lower():
            raise DataError("the store is in use by a running twin", source=path,
                            fix="stop that twin, or read its history over its HTTP API "
                            "(a 'twin run --http': GET /api/history; a hall's shards are read "
                            "once it stops)") from None  # fmt: skip
        raise DataError(f"cannot open the store ({text.splitlines()[0]})", source=path) from None
    except duckdb.Error as exc:
        raise DataError(f"not a DuckDB store ({str(exc).splitlines()[0]})", source=path,
                        fix="give the folder a twin wrote (--store DIR)") from None  # fmt: skip


def _check_format(con: Any, path: Path) -> None:
    """Refuse a DuckDB file that is not a twin store, or one of another format version."""
    try:
        rows = dict(con.execute("SELECT key, value FROM meta").fetchall())
    except Exception:  # noqa: BLE001  any DuckDB catalog error: the table is not there
        rows = {}
    if rows.get("format") != FORMAT:
        raise DataError("not a drafttwin twin store (no format record)", source=path,
                        fix="give the folder 'drafttwin twin run --store' wrote")  # fmt: skip
    if rows.get("version") != str(VERSION):
        raise DataError(f"store format version {rows.get('version')}, this drafttwin reads "
                        f"{VERSION}", source=path, fix="use the drafttwin version that wrote it")  # fmt: skip


class TwinStore:
    """Open (creating if needed) the store in ``folder`` for writing: one per process."""

    def __init__(self, folder: str | Path) -> None:
        self.path = store_path(folder)
        if not self.path.exists() and any(
            store_path(p).is_file() for p in Path(folder).glob("shard-*-of-*")
        ):  # a store beside the shards would hide them from 'twin query' and 'twin audit'
            raise ConfigError("this folder holds the stores of a hall's shards (shard-I-of-K/)",
                              source=folder, where="--store",
                              fix="give 'twin run' a new folder (the hall's is read by 'twin "
                              "query' and 'twin audit')")  # fmt: skip
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.con = _connect(self.path, read_only=False)
        tables = self.con.execute("SELECT count(*) FROM information_schema.tables").fetchall()
        if tables[0][0] == 0:  # new, or a creation killed before its commit: make it whole
            # one transaction: a kill -9 while the store is made leaves all of it or nothing
            self.con.execute("BEGIN TRANSACTION")
            for sql in _SCHEMA:
                self.con.execute(sql)
            self.con.execute("INSERT INTO meta VALUES ('format', ?), ('version', ?)",
                             [FORMAT, str(VERSION)])  # fmt: skip
            self.con.execute("COMMIT")
        _check_format(self.con, self.path)

    def register_machine(self, machine: str, channels: Sequence[str], model: str,
                         source: str) -> None:  # fmt: skip
        """Record a machine's channels; a restart must keep the channel order."""
        row = self.con.execute("SELECT channels FROM machines WHERE machine = ?",
                               [machine]).fetchall()  # fmt: skip
        if row and list(row[0][0]) != list(channels):
            raise DataError(f"machine {machine!r} was stored with channels {list(row[0][0])}, "
                            f"now {list(channels)}", source=self.path,
                            fix="keep the mapping's channels, or use a new --store")  # fmt: skip
        self.con.execute("INSERT OR REPLACE INTO machines VALUES (?, ?, ?, ?)",
                         [machine, list(channels), model, source])  # fmt: skip

    def last_ts_us(self, machine: str) -> int | None:
        """The newest stored sample time of ``machine`` (µs), ``None`` if none: a restart
        resumes after it."""
        row = self.con.execute("SELECT max(ts_us) FROM samples WHERE machine = ?",
                               [machine]).fetchall()  # fmt: skip
        return None if row[0][0] is None else int(row[0][0])

    def commit(self, samples: list[SampleRow], events: list[EventRow]) -> None:
        """Write one batch in one transaction (duplicates of stored keys are dropped)."""
        import pyarrow as pa

        self.con.execute("BEGIN TRANSACTION")
        try:
            if samples:
                batch = _sample_table(samples, pa)  # noqa: F841  read by name in the SQL
                self.con.execute("INSERT OR IGNORE INTO samples SELECT * FROM batch")
            if events:
                ev = pa.table({"machine": [e.machine for e in events],  # noqa: F841
                               "kind": [e.kind for e in events],
                               "ts_us": pa.array([e.ts_us for e in events], pa.int64()),
                               "detail": [e.detail for e in events]})  # fmt: skip
                self.con.execute("INSERT OR IGNORE INTO events SELECT * FROM ev")
            self.con.execute("COMMIT")
        except Exception:
            self.con.execute("ROLLBACK")
            raise

    def apply_retention(self, keep_s: float) -> int:
        """Delete each machine's rows older than ``keep_s`` before its newest sample."""
        keep_us = int(keep_s * 1e6)
        before = self.con.execute("SELECT count(*) FROM samples").fetchall()[0][0]
        for table in ("samples", "events"):
            self.con.execute(
                f"DELETE FROM {table} t USING (SELECT machine, max(ts_us) AS last FROM samples "
                "GROUP BY machine) m WHERE t.machine = m.machine AND t.ts_us < m.last - ?",
                [keep_us],
            )
        return int(before - self.con.execute("SELECT count(*) FROM samples").fetchall()[0][0])

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.con.close()


def _sample_table(rows: list[SampleRow], pa: Any) -> Any:
    k = len(rows[0].measured)

    def lists(name: str) -> Any:
        flat = np.concatenate([np.asarray(getattr(r, name), dtype=np.float64) for r in rows])
        return pa.FixedSizeListArray.from_arrays(pa.array(flat, pa.float64()), k).cast(
            pa.list_(pa.float64())
        )

    return pa.table({
        "machine": [r.machine for r in rows],
        "ts_us": pa.array([r.ts_us for r in rows], pa.int64()),
        "seq": pa.array([r.seq for r in rows], pa.int64()),
        "setpoint": pa.array([r.setpoint for r in rows], pa.float64()),
        **{name: lists(name) for name in KINDS},
    })  # fmt: skip


class StoreWriter:
    """The single writer: rows queued from the event loop, committed every ``commit_ms`` by
    a thread (DuckDB work never blocks the sources). ``on_commit(rows, last_ts_us)`` is called
    after each commit (a log line, a metric). Bounded: past ``max_pending`` queued rows new
    rows are dropped and counted (a disk that cannot keep up must not eat the memory)."""

    def __init__(self, store: TwinStore, commit_ms: float = 200.0, *,
                 retention_s: float | None = None, max_pending: int = 1_000_000,
                 on_commit: Callable[[int, int], None] | None = None) -> None:  # fmt: skip
        self.store = store
        self.commit_s = commit_ms / 1000.0
        self.retention_s = retention_s
        self.on_commit = on_commit
        self._q: queue.SimpleQueue[SampleRow | EventRow] = queue.SimpleQueue()
        self.max_pending = max_pending
        self.dropped = 0
        self.committed = 0
        self.commit_seconds: list[float] = []
        self._stop = threading.Event()
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._loop, name="twin-store", daemon=True)
        self._thread.start()

    def put(self, row: SampleRow | EventRow) -> None:
        if self._q.qsize() >= self.max_pending:
            self.dropped += 1
            return
        self._q.put(row)

    def _drain(self) -> tuple[list[SampleRow], list[EventRow]]:
        samples: list[SampleRow] = []
        events: list[EventRow] = []
        while True:
            try:
                row = self._q.get_nowait()
            except queue.Empty:
                break
            if isinstance(row, SampleRow):
                samples.append(row)
            else:
                events.append(row)
        return samples, events

    def _loop(self) -> None:
        last_retention = time.monotonic()
        try:
            while not self._stop.is_set():
                self._stop.wait(self.commit_s)
                self._flush()
                if self.retention_s is not None and time.monotonic() - last_retention > 10.0:
                    self.store.apply_retention(self.retention_s)
                    last_retention = time.monotonic()
            self._flush()
            if self.retention_s is not None:  # and once more at the end of a run
                self.store.apply_retention(self.retention_s)
        except BaseException as exc:  # noqa: BLE001  surfaced by close() in the main thread
            self.error = exc

    def _flush(self) -> None:
        samples, events = self._drain()
        if not samples and not events:
            return
        start = time.perf_counter()
        self.store.commit(samples, events)
        self.commit_seconds.append(time.perf_counter() - start)
        del self.commit_seconds[:-1000]
        self.committed += len(samples)
        if self.on_commit is not None and samples:
            self.on_commit(len(samples), max(r.ts_us for r in samples))

    def close(self) -> None:
        """Commit what is queued and stop; raise the writer's error if it failed."""
        self._stop.set()
        self._thread.join()
        if self.error is not None:
            raise self.error


__all__ = ["KINDS", "STORE_FILE", "EventRow", "SampleRow", "StoreWriter", "TwinStore",
           "store_path"]  # fmt: skip
