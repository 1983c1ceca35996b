"""What a served plant publishes, channel by channel: unit, engineering range and the
sensor's resolution, derived from the machine itself (not typed in)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from drafttwin.plant.live import MAX_SUPPLY_HZ, LivePlant, LiveSample
from drafttwin.wire.conventions import HERTZ, ROLLER_FIELDS, RPM, Channel, as_measured

SUPPLY_RESOLUTION_HZ = 0.01
"""Resolution of the VFD's output-frequency reading, Hz (a typical drive display; assumption)."""


def plant_channels(plant: LivePlant) -> tuple[Channel, ...]:
    """The rollers, the motor (r/min) and the supply (Hz) of ``plant``. The speed ranges run
    from 0 to the speed at the highest set-point (``MAX_SUPPLY_HZ``), from the machine's own
    speed per hertz (one look-ahead step from a snapshot, undone); the resolution is one
    encoder count per sample window, 60 * rate / counts-per-revolution."""
    s = plant.config.sensors
    resolution = 60.0 * plant.rate_hz / (s.pulses_per_rev * s.quadrature)
    snap = plant.stepper.snapshot()
    try:
        node_rpm = plant.stepper.step(plant.supply_hz)
    finally:
        plant.stepper.restore(snap)
    nodes = [*plant._rollers, plant._motor]
    per_hz = np.abs(node_rpm[nodes]) / max(plant.supply_hz, 1e-9)
    names = (*ROLLER_FIELDS, "motor")
    what = {"front": "front roller speed, measured by its encoder",
            "second": "second roller speed, measured by its encoder",
            "third": "third roller speed, measured by its encoder",
            "back": "back roller speed, measured by its encoder",
            "motor": "main motor speed, measured by its encoder"}  # fmt: skip
    channels = [Channel(n, RPM, (0.0, _ceil_nice(r * MAX_SUPPLY_HZ)), resolution, what[n])
                for n, r in zip(names, per_hz, strict=True)]  # fmt: skip
    channels.append(Channel("supply_hz", HERTZ, (0.0, MAX_SUPPLY_HZ), SUPPLY_RESOLUTION_HZ,
                            "VFD output frequency feeding the main motor"))  # fmt: skip
    return tuple(channels)


def as_published(sample: LiveSample, channels: tuple[Channel, ...]) -> LiveSample:
    """``sample`` with each value as the instrument reports it (rounded to its resolution's
    decimals; NaN stays NaN): what every node, payload and the plant's log carry."""

    def r(v: float, c: Channel) -> float:
        m = as_measured(v, c.decimals)
        return math.nan if m is None else m

    by = {c.name: c for c in channels}
    rollers = np.array([r(v, by[n]) for n, v in zip(ROLLER_FIELDS, sample.rollers_rpm,
                                                     strict=True)])  # fmt: skip
    return dataclasses.replace(sample, rollers_rpm=rollers, motor_rpm=r(sample.motor_rpm,
                               by["motor"]), supply_hz=r(sample.supply_hz, by["supply_hz"]))  # fmt: skip


def values_of(sample: LiveSample) -> dict[str, float]:
    """Field -> value of a sample (the payload's and the scalar nodes' order)."""
    return {**dict(zip(ROLLER_FIELDS, map(float, sample.rollers_rpm), strict=True)),
            "motor": float(sample.motor_rpm), "supply_hz": float(sample.supply_hz)}  # fmt: skip


def _ceil_nice(x: float) -> float:
    """Round up to 1, 2 or 5 times a power of ten (an engineering range a person reads)."""
    if not (math.isfinite(x) and x > 0):
        return 1.0
    p = 10.0 ** math.floor(math.log10(x))
    return next(m * p for m in (1, 2, 5, 10) if m * p >= x)


__all__ = ["SUPPLY_RESOLUTION_HZ", "as_published", "plant_channels", "values_of"]
