"""Where a live twin's samples come from: a replayed file, an OPC UA server, an MQTT broker.

Every source delivers whole rows, one per machine and sample time (a :class:`Sample`): the
machine's output channels, its set-point, a sequence number and the sample's own time stamp.
One vector per machine per tick, not one value per roller: a row arrives whole or not at
all, the sequence number reveals losses and defeats OPC UA's suppression of equal values,
and it costs the transport a fifth of the notifications (docs/twin.md, measured figures).

A source runs as an asyncio task, calls ``emit`` for each sample, reports its state
(``connecting``, ``live``, ``reconnecting``, ``ended``) and reconnects with exponential
backoff; it never blocks another machine's source.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drafttwin.errors import DataError
from drafttwin.twin.mapping import MachineMap

SERVER_QUEUE = 10_000
"""Monitored-item queue asked of an OPC UA server (samples kept while the twin is busy)."""
BACKOFF_S = (0.2, 0.5, 1.0, 2.0, 5.0, 10.0)
"""Waits between reconnect attempts (the last one repeats)."""


@dataclass
class Sample:
    """One row of one machine: values in the order of its mapping's channels."""

    machine: str
    ts_us: int
    seq: int
    values: np.ndarray
    setpoint: float
    motor: float = math.nan  # rpm, for the fault detector (NaN: the source has none)
    received: float = field(default_factory=time.perf_counter)
    sliver: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    """Delivery-sensor readings since the previous sample (delivered m, ktex, time s), where
    the source has a sliver channel."""


Emit = Callable[[Sample], None]
Report = Callable[..., None]  # (machine, kind, detail[, count]): state changes, drops


class Source(ABC):
    """Base class: ``machines`` served, ``state``, ``run(emit, report)``."""

    spec: str = ""
    machines: tuple[MachineMap, ...] = ()
    state: str = "connecting"

    @abstractmethod
    async def run(self, emit: Emit, report: Report) -> None:
        """Deliver samples through ``emit`` and state changes through ``report`` until
        cancelled (or, for a finite source, until it ends)."""

    def _set(self, state: str, report: Report, detail: str = "") -> None:
        if state != self.state:
            self.state = state
            for m in self.machines:
                report(m.name, f"source-{state}", detail or self.spec)


# ---- replay -------------------------------------------------------------------------------
class ReplaySource(Source):
    """A plant (or measured) file replayed at ``speed`` times real time (``inf``: at once)."""

    def __init__(self, path: Path, machine: MachineMap, speed: float = 1.0) -> None:
        from drafttwin.data.io import read_measurements

        self.spec = f"replay:{path}"
        self.machines = (machine,)
        self.speed = speed
        series = read_measurements(path, outputs=list(machine.channels), check_units=False)
        if machine.setpoint not in series.inputs:
            raise DataError(f"no set-point column {machine.setpoint!r}", source=path,
                            fix="replay a file 'drafttwin generate' wrote (it has supply_hz), "
                            "or name the set-point column in the mapping (setpoint = ...)")  # fmt: skip
        self.ts_us = np.round(series.time_s * 1e6).astype(np.int64)
        self.values = series.values
        self.setpoints = np.asarray(series.inputs[machine.setpoint], dtype=np.float64)
        self.motor = (np.full(len(self.ts_us), np.nan) if series.motor_rpm is None
                      else np.asarray(series.motor_rpm, dtype=np.float64))  # fmt: skip
        self.first = 0
        self.sliver = _sliver_channel(path)

    def skip_to(self, after_us: int | None) -> None:
        """Start after ``after_us`` (a restart: those rows are stored already)."""
        if after_us is not None:
            self.first = int(np.searchsorted(self.ts_us, after_us, "right"))

    async def run(self, emit: Emit, report: Report) -> None:
        self._set("live", report)
        name = self.machines[0].name
        start_wall = time.monotonic()
        t0 = self.ts_us[self.first] if self.first < len(self.ts_us) else 0
        for i in range(self.first, len(self.ts_us)):
            if math.isfinite(self.speed):
                due = start_wall + (self.ts_us[i] - t0) / 1e6 / self.speed
                delay = due - time.monotonic()
                # always yield: a loop behind schedule must still let the others run
                await asyncio.sleep(max(delay, 0.0))
            elif i % 50 == 0:
                await asyncio.sleep(0)  # let the other machines and the page run
            emit(Sample(name, int(self.ts_us[i]), i, self.values[i], float(self.setpoints[i]),
                        float(self.motor[i]), sliver=self._sliver_until(i)))  # fmt: skip
        self._set("ended", report)

    def _sliver_until(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The sliver readings delivered after sample ``i - 1`` up to sample ``i``."""
        if self.sliver is None:
            return None
        s, x, t = self.sliver
        lo = 0 if i == 0 else int(np.searchsorted(t, self.ts_us[i - 1] / 1e6, "right"))
        hi = int(np.searchsorted(t, self.ts_us[i] / 1e6, "right"))
        return (s[lo:hi], x[lo:hi], t[lo:hi]) if hi > lo else None


def _sliver_channel(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The delivery sensor's readings recorded beside a replayed file, if any."""
    from drafttwin.sliver import read_sliver
    from drafttwin.sliver.record import sliver_beside

    beside = sliver_beside(path)
    if beside is None:
        return None
    sl = read_sliver(beside.sliver, option="--source replay (its sliver channel)")
    if sl.time_s is None:
        return None
    return sl.delivered_length_m, sl.linear_density_ktex, np.asarray(sl.time_s)


# ---- OPC UA -------------------------------------------------------------------------------
class OpcUaSource(Source):
    """A subscription to each machine's sample node (a Double array laid out as the
    mapping's ``fields``), with queue sizes that keep every sample (docs/twin.md)."""

    def __init__(self, url: str, machines: tuple[MachineMap, ...], publish_ms: float = 10.0,
                 cert_dir: Path | None = None) -> None:  # fmt: skip
        self.spec, self.url, self.machines = f"opcua:{url}", url, machines
        self.publish_ms = publish_ms
        self.cert_dir = cert_dir
        self.silence_s = 5.0
        self.client: Any = None
        self.resume_after: dict[str, int] = {}  # a restart: read the server's history after these

    async def run(self, emit: Emit, report: Report) -> None:
        from asyncua import Client
        from asyncua.common.subscription import DataChangeEvent, OverflowPolicy

        by_node = {m.node: m for m in self.machines}
        attempt = 0
        while True:
            client = Client(self.url, timeout=2.0, watchdog_intervall=1.0)
            try:
                if self.cert_dir is not None:
                    from drafttwin.twin.security import secure_client

                    await secure_client(client, self.cert_dir)
                async with client:
                    self.client = client
                    # server queues of 100 s at 100 Hz (asyncua's cap, 10 000; a spec server
                    # needs at least 2x the samples per publishing interval) and a client queue
                    # of minutes: a stalled loop loses nothing on either side
                    sub = await client.create_subscription(
                        self.publish_ms, None, queue_maxsize=200_000,
                        overflow=OverflowPolicy.DISCONNECT)  # fmt: skip
                    async with sub:
                        nodes = [client.get_node(n) for n in by_node]
                        await sub.subscribe_data_change(nodes, queuesize=SERVER_QUEUE)
                        self._set("live", report)
                        attempt = 0
                        if self.resume_after:  # once, on the first connection after a restart
                            await self._backfill(client, emit, report)
                            self.resume_after = {}
                        while True:
                            # a subscription that goes quiet without an error (opcua-asyncio
                            # #1925) is dropped and made again, like a broken connection
                            ev = await asyncio.wait_for(anext(sub), self.silence_s)
                            if not isinstance(ev, DataChangeEvent):
                                continue
                            m = by_node.get(ev.node.nodeid.to_string())
                            if m is None:
                                continue
                            row = m.from_array(ev.value)
                            if row is None:
                                report(m.name, "dropped", f"malformed value {str(ev.value)[:80]}")
                            else:
                                emit(Sample(m.name, *row))
            except asyncio.CancelledError:
                raise
            except TimeoutError:
                self._set("reconnecting", report, f"no sample for {self.silence_s:g} s")
            except Exception as exc:  # noqa: BLE001  any network / server failure: reconnect
                self._set("reconnecting", report, f"{type(exc).__name__}: {exc}"[:200])
            finally:
                self.client = None
                # bounded: a refused secured session can leave asyncua's disconnect waiting on
                # a reply that never comes, which would hold the twin's shutdown
                with contextlib.suppress(Exception):
                    await asyncio.wait_for(client.disconnect(), 2.0)
            await asyncio.sleep(BACKOFF_S[min(attempt, len(BACKOFF_S) - 1)])
            attempt += 1

    async def _backfill(self, client: Any, emit: Emit, report: Report) -> None:
        """Emit what the server's history holds after each machine's last stored sample (the
        subscription, made first, queues what comes meanwhile; the reorder step drops the
        overlap). A server without history recovers nothing, and says so."""
        import datetime as dt

        from asyncua import ua

        now = dt.datetime.now(dt.UTC)
        for m in self.machines:
            after = self.resume_after.get(m.name)
            if after is None:
                continue
            start = dt.datetime.fromtimestamp(after / 1e6, tz=dt.UTC)
            try:
                node = client.get_node(m.node)
                values = await asyncio.wait_for(node.read_raw_history(start, now), 30.0)
            except (ua.UaError, TimeoutError) as exc:
                report(m.name, "history", f"no history read ({type(exc).__name__}): samples "
                       "published while no twin ran are not recovered")  # fmt: skip
                continue
            rows = [m.from_array(dv.Value.Value) for dv in values if dv.Value is not None]
            fresh = [r for r in rows if r is not None and r[0] > after]
            for row in fresh:  # no receive time: their latency is not the live path's
                emit(Sample(m.name, *row, received=math.nan))
            report(m.name, "history", f"{len(fresh)} samples recovered from the server's history")


__all__ = ["BACKOFF_S", "Emit", "OpcUaSource", "ReplaySource", "Report", "Sample", "Source"]
