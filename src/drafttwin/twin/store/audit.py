"""Count a twin's store against the plant's own log, sample by sample.

For each machine, every sample the plant published (``plant serve --log``) is looked up in the
store by its counter (``seq``) among the stored rows of the log's time span (a restarted plant
counts from 0 again: rows of another run are counted apart, as ``outside``), and the stored row is checked against it: same time stamp,
same measured values. What is not stored is grouped into runs of consecutive counters, each
with the wall-clock span in which the plant published it, so that a caller can tell a loss
by the store (samples the twin had received but not committed when it was killed) from a
restart gap (samples published while no twin ran) from a start-up or shut-down edge.

Rows the twin made up for samples it never received (``seq = -1``: observed as missing) are
counted apart; they are not samples of the plant.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from drafttwin.errors import DataError
from drafttwin.wire.plantlog import read_plant_log

LOG_CHANNELS = ("front", "second", "third", "back", "motor")
"""Channels a plant log carries (a stored channel of another name is not compared)."""


@dataclass
class MissingRun:
    """Consecutive published samples the store lacks."""

    first_seq: int
    last_seq: int
    samples: int
    first_time_s: float
    last_time_s: float
    first_published_s: float
    last_published_s: float


@dataclass
class MachineAudit:
    machine: str
    published: int
    stored: int
    duplicates: int
    mismatched: int
    foreign: int
    filled: int
    before_first: int
    after_last: int
    missing_inside: int
    runs: list[MissingRun] = field(default_factory=list)
    outside: int = 0  # stored rows outside every given log's time span: another run's
    log: str = ""  # the plant log counted against


def _store_rows(folder: Path, machine: str | None) -> tuple[pd.DataFrame, dict[str, list[str]]]:
    """The stored rows (of a single store, or of every shard of a hall)."""
    from drafttwin.twin.store.history import _open, machines_of

    machines = machines_of(folder)
    if machine is not None and machine not in machines:
        raise DataError(f"no machine {machine!r} in the store", source=folder,
                        fix=f"use one of: {', '.join(sorted(machines)) or '(none stored)'}")  # fmt: skip
    frames = []
    for name in sorted(machines) if machine is None else [machine]:
        con, _ = _open(machines[name][0])
        try:
            frames.append(con.execute("SELECT machine, ts_us, seq, measured FROM samples WHERE "
                                      "machine = ? ORDER BY ts_us", [name]).df())  # fmt: skip
        finally:
            con.close()
    frame = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(
        {"machine": [], "ts_us": [], "seq": [], "measured": []})  # fmt: skip
    return frame, {name: chans for name, (_, chans) in machines.items()}


def audit(
    store: str | Path, plant_log: str | Path | Sequence[str | Path], machine: str | None = None
) -> list[MachineAudit]:
    """One :class:`MachineAudit` per machine and plant log (several: the logs of a plant's
    runs, or of several plants) that the store knows; ``outside`` counts a machine's stored
    rows in none of the logs' time spans."""
    paths = [Path(plant_log)] if isinstance(plant_log, str | Path) else [Path(p) for p in plant_log]
    if len(set(paths)) != len(paths):
        raise DataError("a plant log is given twice", source=paths[0], where="--plant-log",
                        fix="give each run's log once")  # fmt: skip
    logs = {p: read_plant_log(p) for p in paths}
    rows, channels = _store_rows(Path(store), machine)
    spans = {p: _spans(log) for p, log in logs.items()}
    _refuse_overlap(spans)
    by_machine = {name: rows[rows["machine"] == name] for name in channels}
    # each machine's stored rows in none of the logs' spans (once, whichever log names it)
    outside = {name: int((~np.any([_within(at, sp[name]) for sp in spans.values() if name in sp],
                                  axis=0)).sum())
               for name, at in by_machine.items() if any(name in sp for sp in spans.values())}  # fmt: skip
    result = []
    for path, log in logs.items():
        names = sorted(set(log["machine"]) & set(channels))
        if machine is not None:
            names = [machine] if machine in set(log["machine"]) else []
        if not names:
            raise DataError("the plant log and the store share no machine", source=path,
                            fix="give the log of the plant this twin read (same machine names)")  # fmt: skip
        mine = []
        for name in names:
            at = by_machine[name]
            mine.append(_machine(name, log[log["machine"] == name], at[_within(at, spans[path][name])],
                                 channels[name], outside[name], path))  # fmt: skip
        if all(not m.stored for m in mine):
            raise DataError("the store holds no sample of this log's time span: the log is of "
                            "another run of the plant", source=path,
                            fix="give the log the plant wrote while this twin ran (plant serve "
                            "--log; a restarted plant writes a log per run)")  # fmt: skip
        result += mine
    return result


SPAN_MARGIN_US = 1_000_000
"""A stored row up to 1 s outside the log's first and last time stamps still belongs to it
(a time stamp written otherwise is counted as differing, not as another run's)."""


def _spans(log: pd.DataFrame) -> dict[str, tuple[int, int]]:
    """Each machine's time span in a log (us, with the margin)."""
    out = {}
    for name, part in log.groupby("machine"):
        ts = part["ts_us"].to_numpy(np.int64)
        out[str(name)] = (int(ts.min()) - SPAN_MARGIN_US, int(ts.max()) + SPAN_MARGIN_US)
    return out


def _within(rows: pd.DataFrame, span: tuple[int, int]) -> np.ndarray:
    ts = rows["ts_us"].to_numpy(np.int64)
    return np.asarray((ts >= span[0]) & (ts <= span[1]))


def _refuse_overlap(spans: dict[Path, dict[str, tuple[int, int]]]) -> None:
    """Two logs of one machine over the same time: their counters could not be told apart."""
    paths = list(spans)
    for i, a in enumerate(paths):
        for b in paths[i + 1 :]:
            for name in set(spans[a]) & set(spans[b]):
                (a0, a1), (b0, b1) = spans[a][name], spans[b][name]
                if a0 < b1 and b0 < a1:
                    raise DataError(f"{a.name} and {b.name} both log machine {name!r} over the "
                                    "same time", source=b, where="--plant-log",
                                    fix="give the logs of separate runs (each run's own log)")  # fmt: skip


def _machine(name: str, log: pd.DataFrame, rows: pd.DataFrame, chans: list[str], outside: int,
             path: Path) -> MachineAudit:  # fmt: skip
    """``rows``: the machine's stored rows within the log's time span (a plant restarted
    counts from 0 again: another run's rows read as stored twice, or differing)."""
    log = log.sort_values("seq").reset_index(drop=True)
    real = rows[rows["seq"] >= 0]
    seq = real["seq"].to_numpy(np.int64)
    duplicates = int(len(seq) - len(np.unique(seq)))
    by_seq = pd.Series(np.arange(len(log)), index=log["seq"].to_numpy(np.int64))
    known = np.isin(seq, by_seq.index)
    foreign = int((~known).sum())
    idx = by_seq.reindex(seq[known]).to_numpy(np.int64)
    mismatched = _mismatched(log.iloc[idx], real[known], chans)
    stored_seq = np.unique(seq[known])
    gone = ~np.isin(log["seq"].to_numpy(np.int64), stored_seq)
    if stored_seq.size:
        lo, hi = stored_seq[0], stored_seq[-1]
        log_seq = log["seq"].to_numpy(np.int64)
        before, after = int((gone & (log_seq < lo)).sum()), int((gone & (log_seq > hi)).sum())
        inside = gone & (log_seq > lo) & (log_seq < hi)
    else:
        before, after, inside = int(gone.sum()), 0, np.zeros(len(log), bool)
    return MachineAudit(name, len(log), int(len(stored_seq)), duplicates, mismatched, foreign,
                        int((rows["seq"] < 0).sum()), before, after, int(inside.sum()),
                        _runs(log, inside), outside, str(path))  # fmt: skip


def _mismatched(log: pd.DataFrame, rows: pd.DataFrame, chans: list[str]) -> int:
    """Stored rows whose time stamp or measured values differ from the published sample."""
    if not len(rows):
        return 0
    bad = log["ts_us"].to_numpy(np.int64) != rows["ts_us"].to_numpy(np.int64)
    measured = np.array([np.asarray(v, np.float64) for v in rows["measured"]])
    for j, ch in enumerate(chans):
        if ch in LOG_CHANNELS:
            a, b = measured[:, j], log[ch].to_numpy(np.float64)
            bad |= ~((a == b) | (np.isnan(a) & np.isnan(b)))
    return int(bad.sum())


def _runs(log: pd.DataFrame, inside: np.ndarray) -> list[MissingRun]:
    k = np.flatnonzero(inside)
    if not k.size:
        return []
    breaks = np.flatnonzero(np.diff(k) > 1)
    starts, ends = np.r_[k[0], k[breaks + 1]], np.r_[k[breaks], k[-1]]
    out = []
    for a, b in zip(starts, ends, strict=True):
        out.append(MissingRun(int(log["seq"][a]), int(log["seq"][b]), int(b - a + 1),
                              float(log["time"][a]), float(log["time"][b]),
                              float(log["published"][a]), float(log["published"][b])))  # fmt: skip
    return out


def as_json(result: list[MachineAudit]) -> list[dict[str, Any]]:
    return [asdict(m) for m in result]


__all__ = ["MachineAudit", "MissingRun", "as_json", "audit"]
