"""``drafttwin plant replay``: recorded files served as live machines over MQTT, faster than
the wall clock if asked.

Each of ``machines`` slots (``NAME-1`` ... ``NAME-N``) plays its share of the files one after
another, as one machine would run them: each file's rows become samples on the slot's clock
(source times from a fixed epoch, :data:`EPOCH_S`, so a run's times are the same every
time), ``gap_s`` of silence between two files (the twin takes it for a stop: its physics
restarts), and before each file the identity of the machine it was recorded on (its
sidecar's machine seed, :func:`~drafttwin.wire.identity.recorded_identity`), retained on
``drafttwin/NAME/identification``: a twin that learned another machine in that slot learns
this one. Samples go out ``batch`` at a time on ``drafttwin/NAME/samples`` (schema
``schemas/samples.schema.json``; a twin reads them as single samples), paced at ``speed``
times real time. A lost row of the record goes out with null speeds, as ``plant serve``
sends a dropped sample. The manifest says which file each slot played when (source times),
so a benchmark can tell an alarm's record.
"""

from __future__ import annotations

import asyncio
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drafttwin._constants import ROLLERS, __version__
from drafttwin.errors import ConfigError, DataError
from drafttwin.plant.serve.closing import say_offline_and_close
from drafttwin.wire.conventions import OFFLINE, ONLINE, parse_hostport, status_topic, topic
from drafttwin.wire.identity import identification_payload, recorded_identity

EPOCH_S = 1_700_000_000.0
"""Source time of each slot's first sample (2023-11-14 22:13:20 UTC): fixed, so that two runs
of one playlist carry the same times."""
MAX_BATCH = 200
"""Most samples in one message (the twin's limit too)."""
IDENTIFY_WAIT_S = 0.3
"""Wall time between a new machine's identification and its first samples."""
LINGER_S = 2.0
"""Wall time the connections stay after the last sample (QoS 0: nothing says it arrived)."""


@dataclass
class Entry:
    """One file a slot plays: where, whose, and when on the slot's clock (source times)."""

    path: Path
    serial: str | None
    start_s: float = math.nan
    end_s: float = math.nan
    rows: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {"file": str(self.path), "serial": self.serial, "start_s": self.start_s,
                "end_s": self.end_s, "rows": self.rows}  # fmt: skip


@dataclass
class Slot:
    """One served machine and the files it plays in turn."""

    name: str
    entries: list[Entry] = field(default_factory=list)
    published: int = 0
    client: Any = None


def playlist(path: Path) -> list[Slot]:
    """Slots from a playlist file: ``{"machines": {"NAME": ["FILE", ...], ...}}`` (files
    relative to the playlist's folder), each machine playing its files in that order."""
    fix = 'write {"machines": {"NAME": ["a.parquet", "b.parquet"]}}'
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise DataError(f"cannot read the playlist ({type(exc).__name__})", source=path,
                        where="--playlist", fix=fix) from None  # fmt: skip
    machines = doc.get("machines") if isinstance(doc, dict) else None
    if not isinstance(machines, dict) or not machines:
        raise DataError("no machines", source=path, where="--playlist", fix=fix)
    slots = []
    for name, files in machines.items():
        if not (isinstance(name, str) and isinstance(files, list) and files
                and all(isinstance(f, str) for f in files)):  # fmt: skip
            raise DataError(f"machine {name!r} has no list of files", source=path,
                            where="--playlist", fix=fix)  # fmt: skip
        slots.append(Slot(name, [Entry(Path(path).parent / f, None) for f in files]))
    return slots


def deal(files: Sequence[Path], name: str, machines: int,
         durations: Sequence[float]) -> list[Slot]:  # fmt: skip
    """The files dealt to ``machines`` slots, each file to the slot with the least running
    time so far (in the files' order): the slots end about together."""
    if machines < 1:
        raise ConfigError(f"{machines} machines", where="--machines", fix="give 1 or more")
    slots = [Slot(name if machines == 1 else f"{name}-{k + 1}") for k in range(machines)]
    load = [0.0] * machines
    for path, dur in zip(files, durations, strict=True):
        k = int(np.argmin(load))
        slots[k].entries.append(Entry(Path(path), None))
        load[k] += dur
    return [s for s in slots if s.entries]


def read_rows(path: Path, columns: dict[str, str] | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """A record's times (s), speeds ``(n, 5)`` (the rollers, then the motor; NaN where lost)
    and set-points (Hz, a lost one carried from the last); ``columns``: file column -> channel
    (``--columns``)."""
    from drafttwin.data.io import read_measurements

    series = read_measurements(path, check_units=False, columns=columns)
    if tuple(series.channels) != ROLLERS or series.motor_rpm is None:
        raise DataError("a replayed record needs the four rollers and the motor", source=path,
                        fix="replay files 'drafttwin generate' (or the fault benchmark) wrote")  # fmt: skip
    if "supply_hz" not in series.inputs:
        raise DataError("no supply_hz column", source=path,
                        fix="replay files 'drafttwin generate' wrote (they have supply_hz)")  # fmt: skip
    supply = np.asarray(series.inputs["supply_hz"], dtype=np.float64).copy()
    ok = np.isfinite(supply)
    if not ok.any():
        raise DataError("supply_hz holds no value", source=path, fix="replay a plant record")
    idx = np.where(ok, np.arange(len(supply)), 0)
    np.maximum.accumulate(idx, out=idx)
    supply = np.where(ok[idx], supply[idx], supply[ok][0])
    speeds = np.column_stack([series.values, series.motor_rpm])
    return np.asarray(series.time_s, dtype=np.float64), speeds, supply


def batch_payload(seq0: int, times: np.ndarray, speeds: np.ndarray,
                  supply: np.ndarray) -> str:  # fmt: skip
    """The JSON of one batch (speeds as recorded, null where lost)."""
    fields = (*ROLLERS, "motor")
    samples = []
    for i in range(len(times)):
        one: dict[str, Any] = {"seq": seq0 + i, "time": round(float(times[i]), 6)}
        for j, f in enumerate(fields):
            v = float(speeds[i, j])
            one[f] = v if math.isfinite(v) else None
        one["supply_hz"] = float(supply[i])
        samples.append(one)
    return json.dumps({"v": 1, "samples": samples}, separators=(",", ":"))


async def replay_mqtt(address: str, slots: list[Slot], *, speed: float = 1.0,
                      batch: int = 20, gap_s: float = 10.0, broker_mode: str = "auto",
                      lead_s: float = 0.0, hold: bool = False,
                      on_entry: Callable[[Slot, Entry], None] | None = None,
                      on_done: Callable[[], None] | None = None,
                      columns: dict[str, str] | None = None) -> list[Slot]:  # fmt: skip
    """Play every slot's files to the broker at ``address`` (see the module docstring);
    returns the slots with each entry's times filled in. ``speed``: ``inf`` publishes as fast
    as the connection takes. ``lead_s``: wait this long after connecting (a twin subscribes
    meanwhile); ``hold``: once played, keep the connections (and an embedded broker) until
    cancelled, so a slower subscriber drains what is queued."""
    from drafttwin.plant.serve.mqtt import _broker_for

    if not (speed > 0):
        raise ConfigError(f"speed {speed}", where="--speed", fix="give a positive factor, e.g. 20")
    if not 1 <= batch <= MAX_BATCH:
        raise ConfigError(f"batch {batch}", where="--batch", fix=f"give 1 to {MAX_BATCH}")
    host, port = parse_hostport(address, "--mqtt")
    broker = await _broker_for(host, port, broker_mode, None, None, None)
    try:
        for s in slots:
            s.client = await _connect(s.name, host, port)
        await asyncio.sleep(lead_s)
        wall0 = time.monotonic()
        await asyncio.gather(
            *(_play(s, speed, batch, gap_s, wall0, on_entry, columns) for s in slots)
        )
        if on_done is not None:
            on_done()
        # QoS 0 has no acknowledgement: give the subscribers a moment (or all the time
        # they need, until cancelled) before the connections and an embedded broker go
        await (asyncio.Event().wait() if hold else asyncio.sleep(LINGER_S))
    finally:
        await say_offline_and_close([(s.name, s.client) for s in slots])
        for s in slots:
            s.client = None
        if broker is not None:
            await broker.shutdown()
    return slots


async def _play(slot: Slot, speed: float, batch: int, gap_s: float, wall0: float,
                on_entry: Callable[[Slot, Entry], None] | None,
                columns: dict[str, str] | None = None) -> None:  # fmt: skip
    clock = EPOCH_S
    for e in slot.entries:
        t, speeds, supply = await asyncio.to_thread(read_rows, e.path, columns)
        who = recorded_identity(e.path)
        e.serial = None if who is None else who.serial
        if who is not None:
            payload = json.dumps(identification_payload(who, __version__))
            slot.client.publish(topic(slot.name, "identification"), payload, qos=1, retain=True)
            await asyncio.sleep(IDENTIFY_WAIT_S)
        src = clock + (t - t[0])
        e.start_s, e.end_s, e.rows = float(src[0]), float(src[-1]), len(t)
        for i in range(0, len(t), batch):
            if math.isfinite(speed):
                delay = wall0 + (src[i] - EPOCH_S) / speed - time.monotonic()
                await asyncio.sleep(max(delay, 0.0))  # always yield: the other slots run
            elif i % (batch * 10) == 0:
                await asyncio.sleep(0)
            j = min(i + batch, len(t))
            text = batch_payload(slot.published + 1, src[i:j], speeds[i:j], supply[i:j])
            slot.client.publish(topic(slot.name, "samples"), text, qos=0)
            slot.published += j - i
        if on_entry is not None:
            on_entry(slot, e)
        clock = e.end_s + gap_s
        # the files' own sample period after a file's last row, then the gap
        clock += float(np.median(np.diff(t))) if len(t) > 1 else 0.0


async def _connect(name: str, host: str, port: int) -> Any:
    import paho.mqtt.client as mqtt

    def on_connect(client: Any, *_: Any) -> None:
        client.publish(status_topic(name), ONLINE, qos=1, retain=True)

    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv311)
    client.on_connect = on_connect
    client.max_queued_messages_set(100_000)
    client.will_set(status_topic(name), OFFLINE, qos=1, retain=True)
    await asyncio.to_thread(client.connect, host, port, 30)
    client.loop_start()
    for _ in range(100):
        if client.is_connected():
            return client
        await asyncio.sleep(0.05)
    raise ConfigError(f"{host}:{port} accepts connections but no MQTT broker answers there",
                      where="--mqtt", fix="give the address of an MQTT broker")  # fmt: skip


def manifest_of(slots: Sequence[Slot], speed: float, gap_s: float) -> dict[str, Any]:
    """What each slot played when (JSON-able)."""
    return {"epoch_s": EPOCH_S, "speed": speed, "gap_s": gap_s,
            "machines": {s.name: [e.to_dict() for e in s.entries] for s in slots}}  # fmt: skip


__all__ = ["EPOCH_S", "Entry", "Slot", "batch_payload", "deal", "manifest_of", "playlist",
           "read_rows", "replay_mqtt"]  # fmt: skip
