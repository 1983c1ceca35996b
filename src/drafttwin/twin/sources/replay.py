"""A plant (or measured) file replayed as a live source, at a speed or at once
(``--source replay:FILE``), with the sliver channel recorded beside it: the delivery sensor's
readings, and where the record has them the infeed readings and the store's length clock
with the leveller's description (its sidecar's ``sliver`` section), as a served plant sends
them."""

from __future__ import annotations

import asyncio
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from drafttwin.errors import DataError
from drafttwin.twin.sources.base import Emit, Report, Sample, Source
from drafttwin.twin.sources.mapping import MachineMap
from drafttwin.wire.identity import recorded_identity
from drafttwin.wire.sliver import SliverBatch


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
        self.sliver, self.sliver_section = _sliver_channel(path)
        self.identity = recorded_identity(path)

    def skip_to(self, after_us: int | None) -> None:
        """Start after ``after_us`` (a restart: those rows are stored already)."""
        if after_us is not None:
            self.first = int(np.searchsorted(self.ts_us, after_us, "right"))

    async def run(self, emit: Emit, report: Report) -> None:
        self._set("live", report)
        name = self.machines[0].name
        if self.sliver_section is not None:  # the leveller's setting, as a served plant says
            report(name, "leveller", json.dumps({"v": 1, **self.sliver_section}))
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
                        float(self.motor[i]), sliver=self._sliver_until(name, i)))  # fmt: skip
        self._set("ended", report)

    def _sliver_until(self, name: str, i: int) -> SliverBatch | None:
        """The sliver readings delivered after sample ``i - 1`` up to sample ``i``."""
        if self.sliver is None:
            return None
        s, x, t, infeed, fed = self.sliver
        lo = 0 if i == 0 else int(np.searchsorted(t, self.ts_us[i - 1] / 1e6, "right"))
        hi = int(np.searchsorted(t, self.ts_us[i] / 1e6, "right"))
        if hi <= lo:
            return None
        return SliverBatch(name, i, t[lo:hi], s[lo:hi], x[lo:hi], infeed[lo:hi], fed[lo:hi])


def _sliver_channel(path: Path) -> tuple[tuple[np.ndarray, ...] | None, dict[str, Any] | None]:
    """The sliver readings recorded beside a replayed file (delivered m, ktex, time s, infeed
    ktex, fed m; the last two NaN where the record has no leveller columns) and its sidecar's
    description of them (None: no leveller columns); None without a sliver channel."""
    from drafttwin.sliver import read_sliver
    from drafttwin.sliver.leveller_record import read_leveller_record
    from drafttwin.sliver.record import sliver_beside

    beside = sliver_beside(path)
    if beside is None:
        return None, None
    option = "--source replay (its sliver channel)"
    try:  # what a levelling drawframe records, read as 'sliver level' reads it
        r = read_leveller_record(path, option=option).record
    except DataError:
        sl = read_sliver(beside.sliver, option=option)
        if sl.time_s is None:
            return None, None
        nan = np.full(sl.linear_density_ktex.size, np.nan)
        return (sl.delivered_length_m, sl.linear_density_ktex, np.asarray(sl.time_s), nan,
                nan), None  # fmt: skip
    section = dict(beside.sidecar)
    if isinstance(section.get("leveller"), dict):  # the setting, not the sidecar's truth
        section["leveller"] = {k: v for k, v in section["leveller"].items()
                               if k not in ("true_action_point_mm", "action_offset_mm")}  # fmt: skip
    return (r.delivered_length_m, r.delivery_ktex, r.time_s, r.infeed_ktex,
            r.fed_length_m), section  # fmt: skip


__all__ = ["ReplaySource"]
