"""A plant (or measured) file replayed as a live source, at a speed or at once
(``--source replay:FILE``), with the delivery sensor's sliver channel recorded beside it."""

from __future__ import annotations

import asyncio
import math
import time
from pathlib import Path

import numpy as np

from drafttwin.errors import DataError
from drafttwin.twin.sources.base import Emit, Report, Sample, Source
from drafttwin.twin.sources.mapping import MachineMap
from drafttwin.wire.identity import recorded_identity


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
        self.identity = recorded_identity(path)

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


__all__ = ["ReplaySource"]
