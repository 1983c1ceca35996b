"""What the twin publishes per machine, in one form for every protocol: its prediction of a
sample (measured, physics, twin, residual per channel, with units), its health and its
current alarm with the probable cause.

The plant's conventions (:mod:`drafttwin.wire.conventions`: UNECE units, ``v``, a
time written twice: ``time`` in epoch seconds and ``timestamp`` in ISO 8601 UTC) hold here
too; the time is the sample's own (the source's clock), never the time of publishing. The
MQTT payloads are these dictionaries as JSON; the OPC UA server writes the same values into
its nodes. Their JSON Schemas ship in the package (:data:`SCHEMA_FILES`).
"""

from __future__ import annotations

import datetime as dt
import json
import math
import time
from importlib import resources
from importlib.resources.abc import Traversable
from typing import Any

from drafttwin.twin.service import MachineState, TwinService
from drafttwin.twin.store.db import EventRow, SampleRow
from drafttwin.wire.conventions import HERTZ, PAYLOAD_VERSION, RPM, SECOND, Unit
from drafttwin.wire.conventions import iso_time as iso_s
from drafttwin.wire.sliver import KTEX, METRE, MILLIMETRE, PERCENT

SCHEMA_FILES = {
    "prediction": "twin-prediction.schema.json",
    "alarm": "twin-alarm.schema.json",
    "status": "twin-status.schema.json",
    "alarms": "twin-alarms.schema.json",
    "sliver": "twin-sliver.schema.json",
}
"""The JSON Schema of each payload, in the package's ``twin/publish/schemas`` folder."""
ALARM_KINDS = ("fault", "sensor-fault", "fault-cause", "fault-cleared", "alarm-ack",
               "sliver-chimney", "sliver-count")  # fmt: skip
"""Events published as alarms, or changes of them (the others change a machine's health)."""
MILLISECOND = Unit("C26", "ms", "millisecond")
UNITS = {"rpm": RPM, "r/min": RPM, "Hz": HERTZ, "s": SECOND, "ms": MILLISECOND, "ktex": KTEX,
         "%": PERCENT, "m": METRE, "mm": MILLIMETRE}  # fmt: skip
"""A unit as a model file or a field name writes it -> its UNECE Rec 20 unit."""


def unit_of(text: str) -> Unit | None:
    return UNITS.get(text)


def symbol(text: str) -> str:
    """The unit's symbol as the plant publishes it (``rpm`` -> ``r/min``)."""
    unit = unit_of(text)
    return text if unit is None else unit.symbol


def iso_time(ts_us: int) -> str:
    """``ts_us`` (microseconds since 1970, UTC) as ISO 8601 UTC with microseconds."""
    return iso_s(ts_us / 1e6)


def utc(ts_us: int) -> dt.datetime:
    """Microseconds since 1970 as an aware UTC datetime (OPC UA SourceTimestamp)."""
    return dt.datetime(1970, 1, 1, tzinfo=dt.UTC) + dt.timedelta(microseconds=int(ts_us))


def stamp(ts_us: int) -> dict[str, Any]:
    """The time fields of a payload: epoch seconds and ISO 8601."""
    return {"time": ts_us / 1e6, "timestamp": iso_time(ts_us)}


def number(x: float) -> float | None:
    """A finite float, or None (JSON has no NaN: a value the twin does not have yet)."""
    x = float(x)
    return x if math.isfinite(x) else None


def setpoint_unit(name: str) -> str:
    """The set-point's unit from its name (the project names quantities with their unit)."""
    return "Hz" if name.endswith("_hz") else ""


def prediction(st: MachineState, row: SampleRow) -> dict[str, Any]:
    """One processed sample: per channel measured, physics, twin prediction and residual."""
    units = st.twin.model.units_
    channels = {
        name: {
            "unit": symbol(units.get(name, "")),
            "measured": number(row.measured[i]),
            "physics": number(row.physics[i]),
            "prediction": number(row.twin[i]),
            "residual": number(row.residual[i]),
        }
        for i, name in enumerate(st.twin.channels)
    }
    sp = st.mapping.setpoint
    return {
        "v": PAYLOAD_VERSION,
        "machine": row.machine,
        "seq": int(row.seq),
        **stamp(row.ts_us),
        "setpoint": {"name": sp, "value": number(row.setpoint), "unit": setpoint_unit(sp)},
        "channels": channels,
    }


def event_detail(ev: EventRow) -> dict[str, Any]:
    """An event's detail: the alarm JSON the fault watch wrote, or its text."""
    try:
        doc = json.loads(ev.detail)
    except ValueError:
        return {"text": ev.detail}
    return doc if isinstance(doc, dict) else {"text": ev.detail}


def probable_cause(detail: dict[str, Any]) -> str | None:
    """The ranking's first element as ``element:kind`` (None: not localised yet)."""
    causes = detail.get("causes") or []
    top = causes[0] if causes else None
    if not isinstance(top, dict) or "element" not in top:
        return None
    return f"{top['element']}:{top.get('kind', '')}"


def alarm(ev: EventRow) -> dict[str, Any]:
    """An alarm event: its kind, the sample time it was raised at, its probable cause."""
    detail = event_detail(ev)
    return {
        "v": PAYLOAD_VERSION,
        "machine": ev.machine,
        "kind": ev.kind,
        **stamp(ev.ts_us),
        "active": True,
        "cause": probable_cause(detail),
        "detail": detail,
    }


class Health:
    """The figures of a machine's health; the twin's p99 latency is computed at most once a
    second (a percentile over 20 000 latencies)."""

    def __init__(self, service: TwinService) -> None:
        self.service = service
        self._p99: float | None = None
        self._p99_at = -math.inf

    def p99_ms(self) -> float | None:
        now = time.monotonic()
        if now - self._p99_at >= 1.0:
            self._p99, self._p99_at = self.service.latency_ms()["p99"], now
        return self._p99

    def status(self, st: MachineState, state: str | None = None) -> dict[str, Any]:
        """The retained status of a machine; ``state`` overrides the twin's (``offline``)."""
        last = st.recent[-1].ts_us if st.recent else None
        # a replayed file's times are its own seconds, not the wall clock: no data age
        wall_clock = last is not None and not st.source.startswith("replay:")
        return {
            "v": PAYLOAD_VERSION,
            "machine": st.twin.name,
            "state": state or st.state,
            **stamp(int(time.time() * 1e6)),
            "last_sample_timestamp": None if last is None else iso_time(last),
            "data_age_s": time.time() - last / 1e6 if wall_clock and last is not None else None,
            "since_last_sample_s": (time.monotonic() - st.last_wall) if st.last_wall else None,
            "latency_p99_ms": self.p99_ms(),
            "received": st.received,
            "processed": st.twin.n_rows,
            "late": st.twin.reorder.late,
            "dropped": st.dropped,
            "detector": detector(st),
            "alarm": None if st.last_fault is None else alarm(st.last_fault),
        }


def sliver(st: MachineState) -> dict[str, Any] | None:
    """The machine's sliver as the twin watches it (running count and CV, the last
    spectrogram's chimneys named) and its leveller (state, setting, the standing
    recommendation): retained on ``PREFIX/NAME/sliver``; None without a sliver channel.
    A recommendation only: the twin never writes a setting."""
    if st.sliver is None and st.level is None:
        return None
    s = None if st.sliver is None else st.sliver.summary()
    watch = None if s is None else {
        **{k: number(s[k]) for k in ("count_ktex", "cv_pct", "delivered_m")},
        **{k: s[k] for k in ("alarms", "chimneys", "count_limit")}}  # fmt: skip
    from drafttwin._json import to_strict

    level = None if st.level is None else to_strict(st.level.summary())  # NaN: null
    return {"v": PAYLOAD_VERSION, "machine": st.twin.name, **stamp(int(time.time() * 1e6)),
            "sliver": watch, "leveller": level}  # fmt: skip


def active_alarms(service: TwinService, machine: str) -> dict[str, Any]:
    """The machine's retained alarms (active, or not yet acknowledged and confirmed), most
    severe first: what the MQTT publisher retains and every late client reads."""
    return {"v": PAYLOAD_VERSION, "machine": machine, **stamp(int(time.time() * 1e6)),
            "alarms": [a.to_dict() for a in service.book.retained(machine)]}  # fmt: skip


def detector(st: MachineState) -> dict[str, Any]:
    """The machine's fault detector: ``none``, ``learning`` (its healthy state: how far, how
    long still, no fault alarm meanwhile) or ``watching``; the serial number it knows."""
    w = st.watch
    state = "none" if w is None else "learning" if w.learning else "watching"
    return {"state": state,
            "progress": None if w is None else round(w.learn_progress, 4),
            "left_s": None if w is None else round(w.learn_left_s, 1),
            "serial_number": None if st.identity is None else st.identity.serial}  # fmt: skip


def schema_dir() -> Traversable:
    """The folder of the shipped JSON Schemas (the page serves them too, under ``/static/``)."""
    return resources.files("drafttwin.twin.publish") / "schemas"


def schema(name: str) -> dict[str, Any]:
    """The shipped JSON Schema of payload ``name`` (``prediction``, ``alarm``, ``status``)."""
    text = (schema_dir() / SCHEMA_FILES[name]).read_text("utf-8")
    doc: dict[str, Any] = json.loads(text)
    return doc


__all__ = [
    "ALARM_KINDS",
    "SCHEMA_FILES",
    "active_alarms",
    "UNITS",
    "Health",
    "alarm",
    "detector",
    "iso_time",
    "prediction",
    "probable_cause",
    "sliver",
    "schema",
    "schema_dir",
    "stamp",
    "symbol",
    "unit_of",
    "utc",
]
