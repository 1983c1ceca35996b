"""The twin's history over HTTP: the store's whole range, paged, downsampled, and bounded.

Heavy history requests must not slow the processing (100 clients asking at once slowed a twin
to 8 rows/s: each request turned thousands of rows into JSON in the event loop's threads). So:

* queries run in :data:`WORKERS` threads of their own, each with its own DuckDB connection to
  the running twin's store (the one process that holds the file); the JSON is built there too;
* at most :data:`MAX_IN_FLIGHT` requests at once, the next gets 429 with ``Retry-After``;
* at most :data:`MAX_PAGE_ROWS` rows per page (``limit``), the rest through the ``next`` cursor;
  ``points`` downsamples a long range to min/max per bucket;
* a query that takes longer than :data:`QUERY_TIMEOUT_S` is interrupted (503).

A request outside these bounds, or a window wholly outside the stored range, gets a 4xx that
says the bound: never a silently shorter answer.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import os
import re
import sys
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from fastapi import HTTPException
from fastapi.responses import Response

from drafttwin._json import to_strict
from drafttwin.twin.service import TwinService
from drafttwin.twin.state import ALARM_KINDS
from drafttwin.twin.store.db import KINDS, EventRow, SampleRow, _connect
from drafttwin.twin.store.history import (
    events_window,
    minmax_rows,
    page_json,
    stored_channels,
    stored_range,
)
from drafttwin.twin.web.bridge import Bridge

T = TypeVar("T")

MAX_PAGE_ROWS = 10_000
"""Rows per page at most (``limit``)."""
DEFAULT_PAGE_ROWS = 5_000
MAX_POINTS = 5_000
"""Buckets of a downsampled answer at most (``points``; two rows each)."""
MAX_SPAN_S = 8 * 86400.0
"""Longest window of one request, s (``seconds``, ``end - start``)."""
MAX_EVENTS = 1_000
"""Events per answer at most."""
MAX_IN_FLIGHT = 4
"""History requests at once; one more gets 429."""
WORKERS = 2
"""Threads that run the queries (one per core of a small box)."""
NICE = 10
"""The history threads' niceness (Linux sets it per thread): the processing thread goes first."""
QUERY_TIMEOUT_S = 10.0
"""A query still running after this is interrupted: 503."""
FAULT_KINDS = ("fault", "fault-cause", "sensor-fault")
"""Events whose detail is JSON (the alarm and its probable cause): parsed into ``fault``."""
COLUMNS = ["time", "seq", "supply_hz", "measured...", "physics...", "twin...", "residual..."]
CHUNK_ROWS = 250
"""Rows per ``json.dumps`` call (a few ms each: the GIL passes between them)."""
_NONFINITE = re.compile(r"-?Infinity|NaN")


def parse_time(text: str, name: str) -> int:
    """Epoch seconds (``1764223200.5``) or ISO 8601 (``2026-11-27T05:00:00Z``; without an
    offset: UTC) to µs; 422 naming the parameter otherwise."""
    try:
        value = float(text)
    except ValueError:
        try:
            when = datetime.fromisoformat(text)
        except ValueError:
            raise HTTPException(422, f"{name}={text!r}: give epoch seconds or ISO 8601 "
                                "(2026-11-27T05:00:00Z)") from None  # fmt: skip
        if when.tzinfo is None:
            when = when.replace(tzinfo=UTC)
        value = when.timestamp()
    if not math.isfinite(value):
        raise HTTPException(422, f"{name}={text!r}: not a finite time")
    if not EARLIEST_S <= value <= LATEST_S:  # DuckDB and the page's dates stop there
        raise HTTPException(422, f"{name}={text[:40]!r}: must be from {EARLIEST_S:g} to "
                            f"{LATEST_S:g} s (1970-01-01 to 9999-12-31 UTC)")  # fmt: skip
    return int(round(value * 1e6))


EARLIEST_S = 0.0
"""The earliest time a request may name, epoch seconds (a replayed file's own clock starts
at 0)."""
LATEST_S = 253402300799.0
"""The latest, 9999-12-31T23:59:59Z (a later one failed in DuckDB and the dates: 500)."""
EARLIEST_US, LATEST_US = int(EARLIEST_S * 1e6), int(LATEST_S * 1e6)


def _iso(us: int) -> str:
    return datetime.fromtimestamp(us / 1e6, UTC).isoformat()


def _bounded(value: int | None, name: str, low: int, high: int, default: int) -> int:
    if value is None:
        return default
    if not low <= value <= high:
        raise HTTPException(422, f"{name}={value}: must be {low}..{high}")
    return value


def _json(meta: dict[str, Any], rows: list[list[Any]], key: str = "rows") -> Response:
    """``meta`` plus ``rows`` as strict JSON (NaN -> null). Encoded :data:`CHUNK_ROWS` at a
    time: one C call over 10 000 rows holds the GIL for ~0.1 s, the processing's thread with it."""
    parts = []
    for i in range(0, len(rows), CHUNK_ROWS):
        parts.append(_NONFINITE.sub("null", json.dumps(rows[i : i + CHUNK_ROWS]))[1:-1])
    head = json.dumps(meta, allow_nan=False)
    body = f'{head[:-1]}, "{key}": [{", ".join(parts)}]}}'
    return Response(body, media_type="application/json")


def _row_lists(a: np.ndarray) -> list[list[Any]]:
    """Rows in the page's layout: time in s, seq an integer, the values."""
    out: list[list[Any]] = a.tolist()
    for r in out:
        r[0] = r[0] / 1e6
        r[1] = None if r[1] != r[1] else int(r[1])
    return out


def memory_rows(rows: list[SampleRow]) -> np.ndarray:
    if not rows:
        return np.empty((0, 3))
    return np.array([[r.ts_us, r.seq, r.setpoint, *np.concatenate([getattr(r, k) for k in KINDS])]
                     for r in rows], dtype=np.float64)  # fmt: skip


def event_dict(e: EventRow) -> dict[str, Any]:
    out = {"machine": e.machine, "kind": e.kind, "time": e.ts_us / 1e6, "detail": e.detail}
    if e.kind in FAULT_KINDS:
        with contextlib.suppress(ValueError):
            out["fault"] = json.loads(e.detail)
    return out


def _lower_priority() -> None:
    """This thread at :data:`NICE` (Linux: per thread; elsewhere the whole process would be
    reniced, so there it is left as it is)."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), NICE)


def _stopping() -> HTTPException:
    return HTTPException(503, "the twin is stopping: ask again once it runs",
                         headers={"Retry-After": "5"})  # fmt: skip


class _Query:
    """One query's connection, so that a timeout can interrupt it."""

    con: Any = None


class HistoryApi:
    """History, alarms and events of ``service``: from its store when it has one (the whole
    stored range), else from the rows it keeps in memory (the last 30 s, said in the answer)."""

    def __init__(self, service: TwinService, bridge: Bridge | None = None) -> None:
        self.service = service
        self.bridge = bridge if bridge is not None else Bridge()
        writer = service.writer
        self.store: Path | None = None if writer is None else writer.store.path
        self.pool = ThreadPoolExecutor(max_workers=WORKERS, thread_name_prefix="history",
                                       initializer=_lower_priority)  # fmt: skip
        self.in_flight = 0
        self.refused = 0
        self.closing = False
        self._local = threading.local()
        self._cons: list[Any] = []

    def close(self) -> None:
        """Stop the threads (a running query is interrupted, it and the waiting ones are
        answered 503) and close their connections."""
        self.closing = True
        self.pool.shutdown(wait=False, cancel_futures=True)
        for con in self._cons:
            con.interrupt()
        self.pool.shutdown(wait=True)
        for con in self._cons:
            con.close()
        self._cons.clear()

    def _con(self) -> Any:
        con = getattr(self._local, "con", None)
        if con is None:  # the same configuration as the writer's: DuckDB shares the database
            assert self.store is not None
            con = self._local.con = _connect(self.store, read_only=False)
            self._cons.append(con)
        return con

    async def run(self, work: Callable[..., T], *args: Any) -> T:
        """``work(con, *args)`` in a history thread: bounded in number and in time."""
        if self.closing:
            raise _stopping()
        if self.in_flight >= MAX_IN_FLIGHT:
            self.refused += 1
            raise HTTPException(429, f"{MAX_IN_FLIGHT} history requests already running "
                                "(the bound); retry in a second", headers={"Retry-After": "1"})  # fmt: skip
        self.in_flight += 1
        q = _Query()

        def job() -> T:
            q.con = self._con() if self.store is not None else None
            return work(q.con, *args)

        submitted = self.pool.submit(job)
        try:
            return await asyncio.wait_for(asyncio.wrap_future(submitted), QUERY_TIMEOUT_S)
        except TimeoutError:
            submitted.cancel()  # still queued: never runs
            if q.con is not None:
                q.con.interrupt()
            raise HTTPException(503, f"the history query ran past {QUERY_TIMEOUT_S:g} s (the "
                                "bound): ask for a shorter window or fewer points") from None  # fmt: skip
        except (asyncio.CancelledError, Exception):
            # close() cancelled or interrupted its query: 'stopping'; a cancellation of the
            # request itself (its task cancelling) stays one
            task = asyncio.current_task()
            if not self.closing or (task is not None and task.cancelling()):
                raise
            raise _stopping() from None
        finally:
            self.in_flight -= 1

    # ---- samples ------------------------------------------------------------------------
    def window(self, seconds: float | None, start: str | None, end: str | None,
               cursor: str | None, newest_us: int | None) -> tuple[int, int]:  # fmt: skip
        """The requested ``[start, end]`` in µs (checked); ``cursor`` continues after a page."""
        if seconds is not None and (start is not None or end is not None):
            raise HTTPException(422, "give seconds (the newest ones) or start/end, not both")
        if seconds is not None:
            if not (math.isfinite(seconds) and 0 < seconds <= MAX_SPAN_S):
                raise HTTPException(422, f"seconds={seconds:g}: must be > 0 and <= {MAX_SPAN_S:g}")
            end_us = newest_us if newest_us is not None else 0
            start_us = end_us - int(round(seconds * 1e6))
        else:
            start_us = parse_time(start, "start") if start is not None else EARLIEST_US
            end_us = parse_time(end, "end") if end is not None else LATEST_US
            if start_us > end_us:
                raise HTTPException(422, "start is after end")
            if start is not None and end is not None and end_us - start_us > MAX_SPAN_S * 1e6:
                raise HTTPException(422, f"end - start = {(end_us - start_us) / 1e6:g} s: at "
                                    f"most {MAX_SPAN_S:g} s per request")  # fmt: skip
        if cursor is not None:
            try:
                after = int(cursor)
            except ValueError:
                after = -1
            if not 0 <= after < 2**62:
                raise HTTPException(422, f"cursor={cursor!r}: give the 'next' of a page")
            if seconds is None and start is None and end is None:  # a cursor alone: one span
                end_us = after + int(MAX_SPAN_S * 1e6)
            start_us = max(start_us, after + 1)
            if start_us > end_us:
                raise HTTPException(422, f"cursor={cursor!r} is past the window's end")
        return start_us, end_us

    async def history(self, machine: str, seconds: float | None, start: str | None,
                      end: str | None, limit: int | None, cursor: str | None,
                      points: int | None) -> Response:  # fmt: skip
        limit = _bounded(limit, "limit", 1, MAX_PAGE_ROWS, DEFAULT_PAGE_ROWS)
        if points is not None:
            _bounded(points, "points", 2, MAX_POINTS, points)
        if self.store is None:  # a snapshot on the twin's loop; the JSON in a history thread
            kept = await self.bridge.call(self._kept, machine)
            return await self.run(self._from_memory, machine, kept, seconds, start, end, limit,
                                  cursor)  # fmt: skip
        return await self.run(self._from_store, machine, seconds, start, end, limit, cursor,
                              points)  # fmt: skip

    def _from_store(self, con: Any, machine: str, seconds: float | None, start: str | None,
                    end: str | None, limit: int, cursor: str | None,
                    points: int | None) -> Response:  # fmt: skip
        channels = stored_channels(con).get(machine)
        if channels is None:
            raise HTTPException(404, f"no machine {machine[:100]!r} in the store")
        got = stored_range(con, machine)
        start_us, end_us = self.window(seconds, start, end, cursor, None if got is None else got[1])
        rng = None if got is None else {"first": got[0] / 1e6, "last": got[1] / 1e6,
                                        "rows": got[2]}  # fmt: skip
        if got is not None and (end_us < got[0] or start_us > got[1]) and cursor is None:
            raise HTTPException(416, f"the window {_iso(start_us)} .. {_iso(end_us)} is outside "
                                f"the stored range {_iso(got[0])} .. {_iso(got[1])}")  # fmt: skip
        k = len(channels)
        meta = self._meta(machine, channels, "store", rng, start_us, end_us, got)
        if points is not None:
            lo, hi = (
                (start_us, end_us) if got is None else (max(start_us, got[0]), min(end_us, got[1]))
            )
            if hi - lo > MAX_SPAN_S * 1e6:
                raise HTTPException(422, f"points over {(hi - lo) / 1e6:g} s: at most "
                                    f"{MAX_SPAN_S:g} s per request; give start and end")  # fmt: skip
            bucket = max(1, -(-(hi - lo + 1) // points))
            a = minmax_rows(con, machine, k, lo, hi, bucket) if got else np.empty((0, 3 + 4 * k))
            meta.update(mode="minmax", points=points, bucket_s=bucket / 1e6, next=None)
            return _json(meta, _row_lists(a))
        text, last, more = page_json(con, machine, k, start_us, end_us, limit)
        meta.update(mode="raw", limit=limit, next=str(last) if more else None)
        head = json.dumps(meta, allow_nan=False)
        return Response(f'{head[:-1]}, "rows": {text}}}', media_type="application/json")

    def _meta(self, machine: str, channels: list[str], source: str, rng: Any, start_us: int,
              end_us: int, got: tuple[int, int, int] | None) -> dict[str, Any]:  # fmt: skip
        clipped = got is not None and start_us < got[0]
        return {"machine": machine, "channels": channels, "columns": COLUMNS, "source": source,
                "stored": rng, "start": max(start_us, got[0]) / 1e6 if got else None,
                "end": min(end_us, got[1]) / 1e6 if got else None, "clipped": clipped}  # fmt: skip

    def _kept(self, machine: str) -> tuple[list[SampleRow], list[str], int]:
        st = self.service.states.get(machine)
        if st is None:
            raise HTTPException(404, f"no machine {machine[:100]!r}")
        return list(st.recent), list(st.mapping.channels), st.recent.maxlen or 0

    def _from_memory(self, _con: None, machine: str, kept: tuple[list[SampleRow], list[str], int],
                     seconds: float | None, start: str | None, end: str | None, limit: int,
                     cursor: str | None) -> Response:  # fmt: skip
        rows, channels, maxlen = kept
        got = (rows[0].ts_us, rows[-1].ts_us, len(rows)) if rows else None
        start_us, end_us = self.window(seconds, start, end, cursor, None if got is None else got[1])
        if got is not None and (end_us < got[0] or start_us > got[1]) and cursor is None:
            raise HTTPException(416, f"the window {_iso(start_us)} .. {_iso(end_us)} is outside "
                                f"the rows kept in memory, {_iso(got[0])} .. {_iso(got[1])}: "
                                "run the twin with --store DIR for its history")  # fmt: skip
        rng = None if got is None else {"first": got[0] / 1e6, "last": got[1] / 1e6, "rows": got[2]}
        meta = self._meta(machine, channels, "memory", rng, start_us, end_us, got)
        picked = [r for r in rows if start_us <= r.ts_us <= end_us]
        more = len(picked) > limit
        picked = picked[:limit]
        meta.update(mode="raw", limit=limit, next=str(picked[-1].ts_us) if more else None)
        meta["note"] = (f"no store: the last {maxlen} rows kept in memory, not "
                        "downsampled; run the twin with --store DIR for its history")  # fmt: skip
        return _json(meta, _row_lists(memory_rows(picked)))

    # ---- events -------------------------------------------------------------------------
    async def events(self, alarms: bool, machine: str | None, start: str | None,
                     end: str | None, limit: int | None) -> Response:  # fmt: skip
        limit = _bounded(limit, "limit", 1, MAX_EVENTS, 200)
        start_us = parse_time(start, "start") if start is not None else EARLIEST_US
        end_us = parse_time(end, "end") if end is not None else LATEST_US
        if self.store is None:

            def kept() -> list[EventRow]:  # on the twin's loop: its lists do not move meanwhile
                if machine is not None and machine not in self.service.states:
                    raise HTTPException(404, f"no machine {machine[:100]!r}")
                return [e for st in self.service.states.values()
                        for e in (st.alarms if alarms else st.events)
                        if start_us <= e.ts_us <= end_us and machine in (None, e.machine)]  # fmt: skip

            found = sorted(await self.bridge.call(kept), key=lambda e: e.ts_us)[-limit:]
        else:
            rows = await self.run(_events_of_known, machine, ALARM_KINDS, not alarms, start_us,
                                  end_us, limit, tuple(self.service.states))  # fmt: skip
            found = [EventRow(*r) for r in rows]
        body = json.dumps(to_strict([event_dict(e) for e in found]), allow_nan=False)
        return Response(body, media_type="application/json")


def _events_of_known(con: Any, machine: str | None, kinds: tuple[str, ...], exclude: bool,
                     start_us: int, end_us: int, limit: int,
                     watched: tuple[str, ...]) -> list[tuple[str, str, int, str]]:  # fmt: skip
    """:func:`events_window`, with a machine neither watched nor stored refused (404, as
    /api/alarms/active and /api/model answer it; the store's answer was an empty list)."""
    if machine is not None and machine not in watched and machine not in stored_channels(con):
        raise HTTPException(404, f"no machine {machine[:100]!r}")
    return events_window(con, machine, kinds, exclude, start_us, end_us, limit)


__all__ = ["ALARM_KINDS", "HistoryApi", "event_dict", "parse_time"]
