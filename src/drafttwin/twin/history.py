"""Reading a twin store back: the history of samples and events as tables."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from drafttwin.errors import DataError
from drafttwin.twin.store import KINDS, _check_format, _connect, store_path

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


def _open(folder: str | Path):  # noqa: ANN202  a DuckDB connection
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


def _window(machine: str | None, t_from_s: float | None, t_to_s: float | None):  # noqa: ANN202
    where, args = "", []
    if t_from_s is not None:
        where += " AND ts_us >= ?"
        args.append(int(round(t_from_s * 1e6)))
    if t_to_s is not None:
        where += " AND ts_us <= ?"
        args.append(int(round(t_to_s * 1e6)))
    return where, args


def _frame(machine: str, channels: list[str], rows: dict) -> pd.DataFrame:
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


def read_events(folder: str | Path, machine: str | None = None) -> pd.DataFrame:
    """Gaps, reconnects, dropped payloads and alarms, oldest first."""
    frames = []
    for one in store_folders(folder):
        con, _ = _open(one)
        try:
            sql = "SELECT machine, kind, ts_us, detail FROM events"
            args = []
            if machine is not None:
                sql += " WHERE machine = ?"
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


__all__ = ["machines_of", "read_events", "read_history", "store_folders", "summary"]
