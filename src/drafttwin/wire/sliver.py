"""The sliver on the wire: what ``plant serve --sliver`` publishes of the drawframe's delivery
and infeed sensors, and how the twin reads it back (checked before it is trusted).

A batch holds the readings of a tenth of a second or so (about 220 at 4.3 m/s and a reading
every 2 mm): per reading its time (epoch s, when its piece passed the front nip), the delivered
length, the delivery sensor's linear density, the infeed scanning rollers' reading held then
and the store's length clock (the feeding rollers' travel). Each field has a unit (UNECE Rec
20: ``SEC``, ``MTR``, ``GF`` gram per metre = ktex) and a resolution the values are rounded
to, as for the speeds (:mod:`drafttwin.wire.conventions`).

* MQTT: ``drafttwin/NAME/sliver``, one JSON object per batch (``schemas/sliver.schema.json``
  of :mod:`drafttwin.plant.serve`): ``v``, ``seq`` (the batch counter), ``timestamp`` (its last
  reading's time, ISO 8601), ``n`` and one list of ``n`` numbers per field, ``units``.
  ``drafttwin/NAME/leveller`` (retained): the sliver's description, as a record's sidecar
  names it (the leveller's setting, the fibres, the sensors; ``schemas/leveller.schema.json``).
* OPC UA: ``NAME/Sliver/block`` (``ns=2;s=NAME.Sliver.block``) a Double array ``seq, n``, then
  the ``n`` values of each field in :data:`SLIVER_FIELDS` order (one notification per batch,
  the twin's); the fields also as AnalogItemType arrays with EngineeringUnits and EURange, and
  ``NAME/Leveller`` with the description (a JSON string) and the setting.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drafttwin.wire.conventions import PAYLOAD_VERSION, SECOND, Channel, Unit, iso_time

KTEX = Unit("GF", "ktex", "kilotex (gram per metre)")
METRE = Unit("MTR", "m", "metre")
MILLIMETRE = Unit("MMT", "mm", "millimetre")
PERCENT = Unit("P1", "%", "percent")
SLIVER_FIELDS = ("time", "delivered_length_m", "linear_density_ktex", "infeed_ktex",
                 "fed_length_m")  # fmt: skip
"""The fields of a batch, in the OPC UA block's order."""
SLIVER_CHANNELS = (
    Channel("time", SECOND, (0.0, 1e11), 1e-6,
            "when the reading's piece of sliver passed the front nip, s since the epoch"),
    Channel("delivered_length_m", METRE, (0.0, 1e7), 1e-4,
            "delivered sliver at the reading, m since the machine started"),
    Channel("linear_density_ktex", KTEX, (0.0, 20.0), 1e-4,
            "delivery sensor (the funnel): the delivered sliver's linear density"),
    Channel("infeed_ktex", KTEX, (0.0, 200.0), 1e-3,
            "infeed scanning rollers: the fed slivers' linear density, the reading held then"),
    Channel("fed_length_m", METRE, (0.0, 1e7), 1e-4,
            "the leveller store's length clock: the feeding rollers' travel, m since the "
            "machine started"),
)  # fmt: skip
MAX_READINGS = 5000
"""Most readings in one batch (a tenth of a second holds about 220)."""
MAX_SLIVER_PAYLOAD = 400_000
"""Largest accepted sliver payload, bytes."""
MAX_DESCRIPTION = 16_384
"""Largest accepted description payload, bytes."""


@dataclass(frozen=True)
class SliverBatch:
    """Readings of one machine's sliver sensors, in delivery order."""

    machine: str
    seq: int
    time_s: np.ndarray
    delivered_m: np.ndarray
    ktex: np.ndarray
    infeed_ktex: np.ndarray
    fed_length_m: np.ndarray
    received: float = field(default_factory=time.perf_counter)

    @property
    def arrays(self) -> tuple[np.ndarray, ...]:
        """The fields in :data:`SLIVER_FIELDS` order."""
        return (self.time_s, self.delivered_m, self.ktex, self.infeed_ktex, self.fed_length_m)

    def published(self) -> SliverBatch:
        """The batch with each value as the instrument reports it (rounded to its channel's
        resolution): what every node, payload and log carries."""
        t, s, x, inf, fed = (np.round(a, c.decimals)
                             for a, c in zip(self.arrays, SLIVER_CHANNELS, strict=True))  # fmt: skip
        return SliverBatch(self.machine, self.seq, t, s, x, inf, fed, received=self.received)


def sliver_payload(batch: SliverBatch) -> dict[str, Any]:
    """One batch as JSON (``schemas/sliver.schema.json``)."""
    t_last = float(batch.time_s[-1]) if batch.time_s.size else 0.0
    out: dict[str, Any] = {"v": PAYLOAD_VERSION, "seq": int(batch.seq),
                           "timestamp": iso_time(t_last), "n": int(batch.time_s.size)}  # fmt: skip
    for name, values in zip(SLIVER_FIELDS, batch.arrays, strict=True):
        out[name] = [None if not math.isfinite(v) else v for v in values.tolist()]
    out["units"] = {c.name: c.unit.symbol for c in SLIVER_CHANNELS}
    return out


def sliver_block(batch: SliverBatch) -> list[float]:
    """The OPC UA block: ``seq, n`` and each field's ``n`` values."""
    return [float(batch.seq), float(batch.time_s.size),
            *np.concatenate(batch.arrays).tolist()]  # fmt: skip


def _checked(machine: str, seq: Any, columns: list[Any], n: int) -> SliverBatch | None:
    """A batch from untrusted values: the counter whole, every field ``n`` finite numbers in
    its range (infeed and fed length may be all missing: NaN), time and fed length not
    decreasing, the delivered length increasing."""
    if isinstance(seq, bool) or not isinstance(seq, int | float) or not math.isfinite(seq):
        return None
    if seq != int(seq) or not 0 <= seq < 2**62 or not 1 <= n <= MAX_READINGS:
        return None
    arrays = []
    for c, col in zip(SLIVER_CHANNELS, columns, strict=True):
        if col is None and c.name in ("infeed_ktex", "fed_length_m"):
            arrays.append(np.full(n, np.nan))
            continue
        if not isinstance(col, list | tuple | np.ndarray) or len(col) != n:
            return None
        if any(isinstance(v, bool) or not isinstance(v, int | float | np.floating) for v in col):
            return None
        a = np.asarray(col, dtype=np.float64)
        lo, hi = c.eu_range
        if not (np.all(np.isfinite(a)) and np.all(a >= lo) and np.all(a <= hi)):
            return None
        arrays.append(a)
    t, s, x, inf, fed = arrays
    if np.any(np.diff(t) < 0) or np.any(np.diff(s) <= 0) or np.any(x <= 0):
        return None
    if np.all(np.isfinite(fed)) and np.any(np.diff(fed) < 0):
        return None
    return SliverBatch(machine, int(seq), t, s, x, inf, fed)


def parse_sliver(machine: str, payload: bytes) -> SliverBatch | str:
    """A batch from an MQTT payload, or why it was dropped."""
    if len(payload) > MAX_SLIVER_PAYLOAD:
        return f"sliver payload of {len(payload)} bytes (limit {MAX_SLIVER_PAYLOAD})"
    try:
        obj = json.loads(payload)
    except (ValueError, RecursionError):
        return "sliver payload is not JSON"
    if not isinstance(obj, dict) or obj.get("v") != PAYLOAD_VERSION:
        return "sliver payload is not a version-1 object"
    n = obj.get("n")
    if isinstance(n, bool) or not isinstance(n, int):
        return "sliver payload without a reading count n"
    batch = _checked(machine, obj.get("seq"), [obj.get(f) for f in SLIVER_FIELDS], n)
    return (
        "sliver payload fields missing, of the wrong type or out of range"
        if batch is None
        else batch
    )


def from_block(machine: str, value: Any) -> SliverBatch | str:
    """A batch from the OPC UA block's value, or why it was dropped."""
    if not isinstance(value, list | tuple | np.ndarray) or len(value) < 2:
        return "sliver block is not an array"
    head = value[1]
    if isinstance(head, bool) or not isinstance(head, int | float) or not math.isfinite(head):
        return "sliver block without a reading count"
    n = int(head)
    if n != head or not 1 <= n <= MAX_READINGS or len(value) != 2 + n * len(SLIVER_FIELDS):
        return f"sliver block of {len(value)} values does not hold its {head!r} readings"
    cols: list[Any] = [list(value[2 + k * n : 2 + (k + 1) * n]) for k in range(len(SLIVER_FIELDS))]
    for k in (3, 4):  # infeed and fed length all NaN: a machine without them
        if all(isinstance(v, float) and math.isnan(v) for v in cols[k]):
            cols[k] = None
    batch = _checked(machine, value[0], cols, n)
    return "sliver block values of the wrong type or out of range" if batch is None else batch


def parse_description(payload: bytes | str) -> dict[str, Any] | str:
    """The sliver's description (a sidecar's ``sliver`` section as a served machine gives it),
    or why it was refused: bounded, a JSON object."""
    if len(payload) > MAX_DESCRIPTION:
        return f"description of {len(payload)} bytes (limit {MAX_DESCRIPTION})"
    try:
        obj = json.loads(payload)
    except (ValueError, RecursionError):
        return "description is not JSON"
    if not isinstance(obj, dict) or obj.get("v") != PAYLOAD_VERSION:
        return "description is not a version-1 object"
    return obj


__all__ = ["KTEX", "MAX_READINGS", "METRE", "MILLIMETRE", "PERCENT", "SLIVER_CHANNELS",
           "SLIVER_FIELDS", "SliverBatch", "from_block", "parse_description", "parse_sliver",
           "sliver_block", "sliver_payload"]  # fmt: skip
