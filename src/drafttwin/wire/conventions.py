"""Conventions shared by the plant's servers and the twin's publishers: units (UNECE Rec 20
common codes, as OPC UA EUInformation carries them), engineering ranges, ISO 8601 times, the
MQTT topics and the JSON payloads.

Units: OPC UA Part 8 §5.6.3 takes the unit from UNECE Recommendation 20; the ``UnitId`` is the
common code's characters packed into an Int32 (``"RPM"`` -> 0x52504D = 5394509, ``"HTZ"`` ->
4740186) in the namespace ``http://www.opcfoundation.org/UA/units/un/cefact``. Rec 20 lists
``RPM`` ("revolutions per minute", symbol r/min) and ``HTZ`` (hertz, Hz).

Times: a sample's time is its source time (when the plant measured it), the same in every
OPC UA node (SourceTimestamp) and every payload. In JSON it is written twice: ``time`` (seconds
since the Unix epoch, a number; what the twin's MQTT source reads) and ``timestamp`` (ISO 8601
UTC with microseconds, ``2026-11-27T05:14:24.120000Z``; what a person or a historian reads).

Nothing here imports asyncua or paho: builders return plain values; the OPC UA helpers that
need asyncua live in :mod:`drafttwin.plant.serve.opcua`.
"""

from __future__ import annotations

import datetime as dt
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from drafttwin.errors import ConfigError

UNECE_NAMESPACE = "http://www.opcfoundation.org/UA/units/un/cefact"
"""EUInformation.NamespaceUri of UNECE Rec 20 units (OPC UA Part 8 §5.6.3)."""
TOPIC_ROOT = "drafttwin"
"""First level of every MQTT topic: ``drafttwin/NAME/sample``, ``drafttwin/NAME/status``..."""
PAYLOAD_VERSION = 1
"""``"v"`` of every JSON payload; raised when a field changes meaning."""
ONLINE, OFFLINE = "online", "offline"
"""Payloads (plain text) of the retained status topic ``drafttwin/NAME/status``: ``online``
once connected, ``offline`` on a clean stop and as the will message the broker sends when the
publisher's connection dies (the convention of e.g. Home Assistant's availability topics)."""


@dataclass(frozen=True)
class Unit:
    """A UNECE Rec 20 unit: common code, symbol, name."""

    code: str
    symbol: str
    name: str

    @property
    def unit_id(self) -> int:
        """OPC UA EUInformation.UnitId: the code's (up to 4) ASCII characters, big-endian."""
        value = 0
        for ch in self.code:
            value = (value << 8) | ord(ch)
        return value


RPM = Unit("RPM", "r/min", "revolutions per minute")
HERTZ = Unit("HTZ", "Hz", "hertz")
SECOND = Unit("SEC", "s", "second")
UNITLESS = Unit("C62", "1", "one")  # Rec 20 "one": a count (the sample counter)


@dataclass(frozen=True)
class Channel:
    """One published quantity: its name (the JSON field and OPC UA browse name), unit,
    engineering range (low, high: what normal operation reaches), resolution (the smallest
    step the sensor reports; values are rounded to it) and a description."""

    name: str
    unit: Unit
    eu_range: tuple[float, float]
    resolution: float
    description: str

    @property
    def decimals(self) -> int:
        return decimals_of(self.resolution)


ROLLER_FIELDS = ("front", "second", "third", "back")
"""The four drafting rollers, in the order of the ``sample`` array and the payload."""
SAMPLE_FIELDS = ("seq", "time", *ROLLER_FIELDS, "motor", "supply_hz")
"""The ``sample`` array's elements (OPC UA) and the payload's number fields (MQTT)."""


def decimals_of(resolution: float) -> int:
    """Decimal places that write ``resolution`` exactly (0.6 -> 1, 0.05 -> 2, 3 -> 0)."""
    if not (math.isfinite(resolution) and resolution > 0):
        raise ValueError(f"resolution {resolution!r}")
    for d in range(10):
        if abs(round(resolution, d) - resolution) <= 1e-9 * resolution:
            return d
    return 10


def as_measured(value: float, decimals: int) -> float | None:
    """The value as the instrument reports it: no binary noise of the unit conversion
    (1813.8000000000002 -> 1813.8); ``None`` for a dropped measurement (NaN)."""
    v = float(value)
    return round(v, decimals) if math.isfinite(v) else None


def iso_time(t_s: float) -> str:
    """ISO 8601 UTC with microseconds and a ``Z`` (RFC 3339) for epoch seconds ``t_s``."""
    stamp = dt.datetime.fromtimestamp(t_s, tz=dt.UTC)
    return stamp.strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def utc(t_s: float) -> dt.datetime:
    """Epoch seconds as an aware UTC datetime (OPC UA SourceTimestamp)."""
    return dt.datetime.fromtimestamp(t_s, tz=dt.UTC)


def topic(machine: str, kind: str) -> str:
    """``drafttwin/MACHINE/KIND`` (kinds: sample, setpoint, status; the twin adds its own)."""
    return f"{TOPIC_ROOT}/{machine}/{kind}"


def units_of(channels: Sequence[Channel]) -> dict[str, str]:
    """Field -> unit symbol, carried in every payload."""
    return {c.name: c.unit.symbol for c in channels}


def sample_payload(
    seq: int,
    t_s: float,
    values: Mapping[str, float],
    channels: Sequence[Channel],
    *,
    lag_s: float | None = None,
) -> dict[str, Any]:
    """One sample as JSON (schema ``schemas/sample.schema.json``): counter, source time
    (epoch s and ISO 8601), each channel as measured (``null``: dropped), the units, and how
    late the publisher sent it (``lag_s``, wall clock minus source time) when known."""
    payload: dict[str, Any] = {"v": PAYLOAD_VERSION, "seq": int(seq), "time": float(t_s),
                               "timestamp": iso_time(t_s)}  # fmt: skip
    for c in channels:
        payload[c.name] = as_measured(values[c.name], c.decimals)
    payload["units"] = units_of(channels)
    if lag_s is not None:
        payload["lag_s"] = round(float(lag_s), 4)
    return payload


__all__ = [
    "HERTZ",
    "OFFLINE",
    "ONLINE",
    "PAYLOAD_VERSION",
    "ROLLER_FIELDS",
    "RPM",
    "SAMPLE_FIELDS",
    "SECOND",
    "TOPIC_ROOT",
    "UNECE_NAMESPACE",
    "UNITLESS",
    "Channel",
    "Unit",
    "as_measured",
    "decimals_of",
    "iso_time",
    "sample_payload",
    "topic",
    "units_of",
    "utc",
]


def parse_hostport(text: str, where: str) -> tuple[str, int]:
    host, _, port = text.removeprefix("mqtt://").rstrip("/").rpartition(":")
    if "://" in host:  # another scheme (opc.tcp://...) read as a host
        raise ConfigError(f"{text!r} is not an MQTT address", where=where,
                          fix=f"write HOST:PORT or mqtt://HOST:PORT, e.g. "
                          f"{host.partition('://')[2] or '127.0.0.1'}:{port or 1883}")  # fmt: skip
    if not host or not port.isdigit() or not 0 < int(port) < 65536 or "/" in host:
        raise ConfigError(f"bad MQTT address {text!r}", where=where,
                          fix="write HOST:PORT, e.g. 127.0.0.1:1883")  # fmt: skip
    return host, int(port)


def setpoint_topic(machine: str) -> str:
    return topic(machine, "setpoint")


def status_topic(machine: str) -> str:
    return topic(machine, "status")
