"""Reading a twin store back: the history of samples and events as tables."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from drafttwin.errors import DataError
from drafttwin.twin.store.db import KINDS, _check_format, _connect, store_path

SUFFIX = {"measured": "", "physics": "_physics", "twin": "_twin", "residual": "_residual"}
"""Column suffix of each kind in an exported table: ``front``, ``front_physics``, ..."""


def store_folders(folder: str | Path) -> list[Path]:
    """The store in ``folder``, or the shards' stores of a hall (``shard-I-of-K/``)."""
    folder = Path(folder)
    if store_path(folder).is_file():
        return [folder]
    shards = sorted(p for p in folder.glob("shard-*-of-*") if store_path(p).is_file())
    if not shards:
        raise DataError("no twin store here", source=folder,
                        fix="give the folder 'drafttwin twin run --store DIR' (or 'twin hall') "
                        "wrote")  # fmt: skip
    return shards


def _open(folder: str | Path) -> tuple[Any, Path]:  # a DuckDB connection (Any, as in db)
    path = store_path(folder)
    if not path.is_file():
        raise DataError("no twin store here", source=path.parent,
                        fix="give the folder 'drafttwin twin run --store DIR' wrote")  # fmt: skip
    con = _connect(path, read_only=True)
    _check_format(con, path)
    return con, path


def machines_of(folder: str | Path) -> dict[str, tuple[Path, list[str]]]:
    """Every stored machine: (its store folder, its channels)."""
    out: dict[str, tuple[Path, list[str]]] = {}
    for one in store_folders(folder):
        con, _ = _open(one)
        try:
            for name, chans in con.execute("SELECT machine, channels FROM machines").fetchall():
                out[name] = (one, list(chans))
        finally:
            con.close()
    return out


def read_history(folder: str | Path, machine: str | None = None, t_from_s: float | None = None,
                 t_to_s: float | None = None) -> pd.DataFrame:  # fmt: skip
    """Samples of one machine (or all) between two times (s, inclusive), oldest first:
    ``machine, time, seq, supply_hz`` then per channel the measured value and its
    ``_physics``, ``_twin`` and ``_residual``. A hall's folder reads every shard's store."""
    machines = machines_of(folder)
    if machine is not None and machine not in machines:
        raise DataError(f"no machine {machine!r} in the store", source=Path(folder),
                        fix=f"use one of: {', '.join(sorted(machines)) or '(none stored)'}")  # fmt: skip
    where, args = _window(machine, t_from_s, t_to_s)
    frames = []
    for name in sorted(machines) if machine is None else [machine]:
        con, _ = _open(machines[name][0])
        try:
            rows = con.execute(
                "SELECT ts_us, seq, setpoint, measured, physics, twin, residual FROM samples "
                f"WHERE machine = ? {where} ORDER BY ts_us", [name, *args],
            ).fetchnumpy()  # fmt: skip
        finally:
            con.close()
        frames.append(_frame(name, machines[name][1], rows))
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def _window(
    machine: str | None, t_from_s: float | None, t_to_s: float | None
) -> tuple[str, list[int]]:
    where = ""
    args: list[int] = []
    if t_from_s is not None:
        where += " AND ts_us >= ?"
        args.append(int(round(t_from_s * 1e6)))
    if t_to_s is not None:
        where += " AND ts_us <= ?"
        args.append(int(round(t_to_s * 1e6)))
    return where, args


def _frame(machine: str, channels: list[str], rows: dict[str, Any]) -> pd.DataFrame:
    n = len(rows["ts_us"])
    cols: dict[str, object] = {
        "machine": np.full(n, machine, dtype=object),
        "time": np.asarray(rows["ts_us"], dtype=np.int64) / 1e6,
        "seq": np.asarray(rows["seq"], dtype=np.int64),
        "supply_hz": np.asarray(rows["setpoint"], dtype=np.float64),
    }
    k = len(channels)
    for kind in KINDS:
        values = np.array([np.asarray(v, dtype=np.float64) for v in rows[kind]]).reshape(n, k)
        for j, ch in enumerate(channels):
            cols[f"{ch}{SUFFIX[kind]}"] = values[:, j]
    return pd.DataFrame(cols)


def read_events(folder: str | Path, machine: str | None = None, t_from_s: float | None = None,
                t_to_s: float | None = None) -> pd.DataFrame:  # fmt: skip
    """Gaps, reconnects, dropped payloads and alarms, oldest first, within ``t_from_s`` ..
    ``t_to_s`` where given (alarms carry the data's time, the twin's own events the wall
    clock: a replay's window in its file's seconds holds its alarms only)."""
    frames = []
    window, window_args = _window(machine, t_from_s, t_to_s)
    for one in store_folders(folder):
        con, _ = _open(one)
        try:
            sql = "SELECT machine, kind, ts_us, detail FROM events WHERE TRUE" + window
            args: list[object] = [*window_args]
            if machine is not None:
                sql += " AND machine = ?"
                args.append(machine)
            frames.append(con.execute(sql, args).df())
        finally:
            con.close()
    frame = pd.concat(frames, ignore_index=True).sort_values("ts_us", kind="stable")
    frame = frame.reset_index(drop=True)
    frame["time"] = frame.pop("ts_us") / 1e6
    return frame


def summary(folder: str | Path) -> list[dict[str, object]]:
    """Per machine: sample count, first and last time (s), events."""
    rows = []
    for one in store_folders(folder):
        con, _ = _open(one)
        try:
            rows += con.execute(
                "SELECT m.machine, count(s.ts_us), min(s.ts_us), max(s.ts_us), "
                "(SELECT count(*) FROM events e WHERE e.machine = m.machine) "
                "FROM machines m LEFT JOIN samples s ON s.machine = m.machine "
                "GROUP BY m.machine"
            ).fetchall()
        finally:
            con.close()
    rows.sort(key=lambda r: r[0])
    return [{"machine": r[0], "samples": int(r[1]),
             "first_s": None if r[2] is None else r[2] / 1e6,
             "last_s": None if r[3] is None else r[3] / 1e6, "events": int(r[4])}
            for r in rows]  # fmt: skip


# ---- queries of a running twin's store (its HTTP API; a connection of that process) -------
def value_columns(k: int) -> list[str]:
    """The per-channel values as plain columns (``measured[1]`` ...), in the row layout's order."""
    return [f"{kind}[{j}]" for kind in KINDS for j in range(1, k + 1)]


def stored_range(con: Any, machine: str) -> tuple[int, int, int] | None:
    """``(first ts_us, last ts_us, rows)`` of ``machine`` in the store; ``None``: no sample."""
    first, last, n = con.execute("SELECT min(ts_us), max(ts_us), count(*) FROM samples "
                                 "WHERE machine = ?", [machine]).fetchall()[0]  # fmt: skip
    return None if first is None else (int(first), int(last), int(n))


def stored_channels(con: Any) -> dict[str, list[str]]:
    """Every machine the store knows, with its channels."""
    return {m: list(c) for m, c in con.execute("SELECT machine, channels FROM machines").fetchall()}


def page_json(con: Any, machine: str, k: int, start_us: int, end_us: int,
              limit: int) -> tuple[str, int | None, bool]:  # fmt: skip
    """Up to ``limit`` samples of ``machine`` with ``start_us <= ts_us <= end_us``, oldest first,
    as a JSON array of rows ``[time s, seq, set-point, values (:func:`value_columns`)]``, NaN as
    null; with the last row's ts_us and whether more rows follow in the window. DuckDB writes
    the JSON (exact round trip of every double) outside the GIL: a history page must not stall
    the twin's processing thread."""
    vals = ", ".join(f"if(isfinite({c}), {c}, NULL)" for c in ["setpoint", *value_columns(k)])
    text, last = con.execute(
        f"SELECT string_agg(json_array(ts_us / 1e6, seq, {vals})::VARCHAR, ',' ORDER BY ts_us), "
        "max(ts_us) FROM (SELECT * FROM samples WHERE machine = ? AND ts_us BETWEEN ? AND ? "
        "ORDER BY ts_us LIMIT ?)", [machine, start_us, end_us, limit],
    ).fetchall()[0]  # fmt: skip
    if last is None:
        return "[]", None, False
    more = con.execute("SELECT count(*) FROM (SELECT 1 FROM samples WHERE machine = ? AND "
                       "ts_us > ? AND ts_us <= ? LIMIT 1)", [machine, last, end_us]).fetchall()  # fmt: skip
    return f"[{text}]", int(last), more[0][0] > 0


def minmax_rows(con: Any, machine: str, k: int, start_us: int, end_us: int,
                bucket_us: int) -> np.ndarray:  # fmt: skip
    """Each ``bucket_us`` bucket of the window as two rows in the layout of :func:`page_json`:
    its minima at the bucket's first sample time, its maxima at the bucket's middle, as an
    ``(n, 3 + 4k)`` array (times in µs). The seq of
    the first is the bucket's first seq, of the second its last: a long range drawn with its
    spikes and extremes, in a bounded number of rows."""
    aggs = ", ".join(f"min({c}), max({c})" for c in ["setpoint", *value_columns(k)])
    got = con.execute(
        f"SELECT min(ts_us), min(seq), max(seq), {aggs} FROM samples WHERE machine = ? AND "
        "ts_us BETWEEN ? AND ? GROUP BY (ts_us - ?) // ? ORDER BY 1",
        [machine, start_us, end_us, start_us, bucket_us],
    ).fetchall()  # fmt: skip
    if not got:
        return np.empty((0, 3 + 4 * k))
    a = np.array(got, dtype=np.float64)
    t0 = a[:, 0]
    mid = start_us + ((t0 - start_us) // bucket_us + 0.5) * bucket_us
    lows = np.column_stack([t0, a[:, 1], a[:, 3::2]])
    highs = np.column_stack([np.maximum(mid, t0 + 1), a[:, 2], a[:, 4::2]])
    return np.stack([lows, highs], axis=1).reshape(-1, lows.shape[1])


def events_window(con: Any, machine: str | None, kinds: tuple[str, ...], exclude: bool,
                  start_us: int, end_us: int, limit: int) -> list[tuple[str, str, int, str]]:  # fmt: skip
    """The newest ``limit`` events (of ``kinds``, or all but them) in the window, oldest first."""
    marks = ", ".join("?" * len(kinds))
    where = f"kind {'NOT ' if exclude else ''}IN ({marks}) AND ts_us BETWEEN ? AND ?"
    args: list[Any] = [*kinds, start_us, end_us]
    if machine is not None:
        where += " AND machine = ?"
        args.append(machine)
    # an alarm and its cause share a time stamp: the cause after its alarm (the insertion
    # order is not kept: INSERT OR IGNORE may reorder), then by kind, so every read agrees
    rows = con.execute(f"SELECT machine, kind, ts_us, detail FROM events WHERE {where} "
                       "ORDER BY ts_us DESC, kind = 'fault-cause' DESC, kind DESC, machine DESC "
                       "LIMIT ?", [*args, limit]).fetchall()  # fmt: skip
    return [(m, kd, int(t), d) for m, kd, t, d in reversed(rows)]


ALARM_BOOK_KINDS = ("fault", "sensor-fault", "fault-cause", "fault-cleared", "alarm-ack")
"""The events the alarm book is made of (raised, caused, cleared, acknowledged)."""
ALARM_BOOK_EVENTS = 5000
"""Of those, the newest read back per machine at a restart."""


def stored_alarm_events(con: Any, machines: list[str]) -> list[Any]:
    """Each machine's newest :data:`ALARM_BOOK_EVENTS` alarm-book events, as ``EventRow``."""
    from drafttwin.twin.store.db import EventRow

    out = []
    for machine in machines:
        rows = events_window(con, machine, ALARM_BOOK_KINDS, False, 0, 2**62, ALARM_BOOK_EVENTS)
        out += [EventRow(*r) for r in rows]
    return out


__all__ = ["ALARM_BOOK_KINDS", "events_window", "stored_alarm_events", "machines_of", "minmax_rows", "page_json", "read_events",
           "read_history", "store_folders", "stored_channels", "stored_range", "summary",
           "value_columns"]  # fmt: skip
