"""The mapping file: which OPC UA node or MQTT topic is which machine, channel and unit.

A TOML file with one ``[[machine]]`` table per machine::

    [[machine]]
    name = "df-01"                       # the machine's name in the store and on the page
    model = "df01.dtm"                   # its model (default: --model)
    rate_hz = 100                        # its sample rate
    setpoint = "supply_hz"               # the channel that drives the physics (VFD supply, Hz)
    node = "ns=2;s=df-01.sample"         # OPC UA: a Double array node, laid out as `fields`
    topic = "drafttwin/df-01/sample"     # MQTT: JSON objects keyed by `fields`
    fields = ["seq", "time", "front", "second", "third", "back", "motor", "supply_hz"]

``seq`` is the machine's sample counter, ``time`` the sample time (s since the epoch, or the
machine's clock); the model's channels and the set-point must be among the fields. Without a
mapping file a source serves one machine laid out as ``drafttwin plant serve`` publishes it.
Every value read from the wire is checked (:meth:`MachineMap.row`): a malformed sample is
dropped and counted, never trusted.
"""

from __future__ import annotations

import math
import time
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel as Schema
from pydantic import ConfigDict, Field, ValidationError

from drafttwin.errors import ConfigError

DEFAULT_FIELDS = ("seq", "time", "front", "second", "third", "back", "motor", "supply_hz")
"""The layout ``drafttwin plant serve`` publishes (OPC UA array and MQTT JSON keys)."""
MAX_ABS = 1e7
"""Largest magnitude accepted for a channel value (rpm); beyond it a payload is hostile or
broken, not a measurement."""
MAX_SEQ = 2**62
Row = tuple[int, int, np.ndarray, float, float]
"""A checked sample: time (us), counter, channel values, set-point, motor speed (NaN: none)."""


def default_node(machine: str) -> str:
    return f"ns=2;s={machine}.sample"


def default_topic(machine: str) -> str:
    return f"drafttwin/{machine}/sample"


@dataclass(frozen=True)
class MachineMap:
    """One machine: where its samples come from and how a sample is laid out."""

    name: str
    channels: tuple[str, ...]
    setpoint: str = "supply_hz"
    rate_hz: float = 100.0
    model: Path | None = None
    node: str = ""
    topic: str = ""
    fields: tuple[str, ...] = DEFAULT_FIELDS

    def __post_init__(self) -> None:
        missing = [
            c for c in (*self.channels, self.setpoint, "seq", "time") if c not in self.fields
        ]
        if missing:
            raise ConfigError(f"machine {self.name!r}: fields lack {missing}",
                              where="fields", fix=f"list every one of {missing} in fields")  # fmt: skip
        object.__setattr__(self, "_index", [self.fields.index(c) for c in self.channels])
        if not self.node:
            object.__setattr__(self, "node", default_node(self.name))
        if not self.topic:
            object.__setattr__(self, "topic", default_topic(self.name))

    def renamed(self, name: str) -> MachineMap:
        return replace(self, name=name, node="", topic="")

    @property
    def has_motor(self) -> bool:
        """The samples carry the motor speed (the fault detector's fifth channel)."""
        return "motor" in self.fields and "motor" not in self.channels

    def row(self, get: Any) -> Row | None:
        """``(ts_us, seq, values, setpoint, motor_rpm)`` from a sample whose field ``f`` is
        ``get(f)``; ``None`` if any field is missing, of the wrong type, out of range or not
        finite (NaN is allowed for a channel: a missing measurement; the motor is NaN when the
        layout has none)."""
        try:
            seq, t, sp = get("seq"), get("time"), get(self.setpoint)
            values = [get(c) for c in self.channels]
            motor = get("motor") if self.has_motor else None
        except (KeyError, IndexError, TypeError):
            return None
        values = [math.nan if v is None else v for v in values]  # null: a dropped measurement
        motor = math.nan if motor is None else motor
        if not all(_is_number(v) for v in (seq, t, sp, motor, *values)):
            return None
        seq_f, t_f, sp_f = float(seq), float(t), float(sp)
        if not (math.isfinite(seq_f) and 0 <= seq_f < MAX_SEQ and seq_f == int(seq_f)):
            return None
        if not (
            math.isfinite(t_f) and 0 <= t_f < 1e11 and math.isfinite(sp_f) and 0 <= sp_f <= 1e3
        ):
            return None
        arr = np.array(values, dtype=np.float64)
        if (np.abs(arr[np.isfinite(arr)]) > MAX_ABS).any() or np.isinf(arr).any():
            return None
        motor_f = float(motor)
        if math.isinf(motor_f) or abs(motor_f) > MAX_ABS:
            return None
        return int(round(t_f * 1e6)), int(seq_f), arr, sp_f, motor_f

    def from_array(self, value: Any) -> Row | None:
        """A row from an OPC UA array value laid out as ``fields``."""
        if not isinstance(value, list | tuple | np.ndarray) or len(value) != len(self.fields):
            return None
        return self.row(lambda f: value[self.fields.index(f)])

    def from_json(self, obj: Any) -> Row | None:
        """A row from a decoded JSON object keyed by ``fields``."""
        if not isinstance(obj, dict):
            return None
        return self.row(lambda f: obj[f])


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float | np.floating | np.integer) and not isinstance(v, bool)


MACHINE_NAME = r"^[A-Za-z0-9_.\-]{1,100}$"
"""A machine's name: letters, digits, '_', '.', '-' (an MQTT topic level and an OPC UA
browse name alike: no wildcard, no '/'), at most 100 characters."""


class _MachineSchema(Schema):
    model_config = ConfigDict(extra="forbid")
    name: str = Field(min_length=1, max_length=100, pattern=MACHINE_NAME)
    model: str | None = None
    rate_hz: float = Field(default=100.0, gt=0, le=10_000)
    setpoint: str = "supply_hz"
    node: str = ""
    topic: str = ""
    fields: list[str] = Field(default_factory=lambda: list(DEFAULT_FIELDS), min_length=3)


class _MappingSchema(Schema):
    model_config = ConfigDict(extra="forbid")
    machine: list[_MachineSchema] = Field(min_length=1, max_length=10_000)


def read_mapping(path: Path, channels: tuple[str, ...]) -> tuple[MachineMap, ...]:
    """The machines of a mapping file (``channels``: the model's output channels)."""
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"not valid TOML ({exc})", source=path, fix="fix the syntax") from None
    try:
        spec = _MappingSchema.model_validate(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(str(p) for p in err["loc"])
        raise ConfigError(err["msg"], source=path, where=where,
                          fix="see docs/twin.md, 'Mapping files'") from None  # fmt: skip
    names = [m.name for m in spec.machine]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ConfigError(f"machine(s) {dup} named twice", source=path,
                          fix="give every machine its own name")  # fmt: skip
    out = []
    for m in spec.machine:
        model = None if m.model is None else (path.parent / m.model)
        try:
            out.append(MachineMap(m.name, channels, m.setpoint, m.rate_hz, model, m.node, m.topic,
                                  tuple(m.fields)))  # fmt: skip
        except ConfigError as exc:
            raise ConfigError(exc.problem, source=path, where=f"machine {m.name!r}",
                              fix=exc.fix) from None  # fmt: skip
    return tuple(out)


def now_s() -> float:
    return time.time()


__all__ = ["DEFAULT_FIELDS", "MachineMap", "default_node", "default_topic", "read_mapping"]
