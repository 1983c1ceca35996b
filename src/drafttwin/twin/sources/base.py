"""What every live source delivers (a :class:`Sample`) and is (a :class:`Source`).

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

import math
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from drafttwin.twin.sources.mapping import MachineMap
from drafttwin.wire.sliver import SliverBatch

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
    sliver: SliverBatch | None = None
    """The sliver sensors' readings since the previous sample, where a replayed record has a
    sliver channel (live sources emit their batches on their own)."""


Emit = Callable[[Sample | SliverBatch], None]
"""A source's samples, and the batches of sliver readings a live source receives."""
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


__all__ = ["BACKOFF_S", "Emit", "Report", "Sample", "SliverBatch", "Source"]
