"""Which measured channels drive a train and which of its nodes they measure.

A drive-train declaration may map measurement columns onto the model: ``[[input]]`` tables
say which column sets the motor's VFD supply frequency or an external torque (with a linear
``gain`` and ``offset`` from the column's unit), ``[[output]]`` tables say which node each
measured output column reads and in which unit. Without the tables the defaults are: a
``supply_hz`` column drives the motor (if there is one); the outputs are every roller by its
roller name, every node by its node name and ``motor`` for the motor node, all in rpm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drafttwin.mechanics.components import (
    OUTPUT_UNITS,
    ROLLER_NAMES,
    InputChannel,
    OutputChannel,
)
from drafttwin.mechanics.config import TrainSpec, output_target

DEFAULT_SUPPLY_CHANNEL = "supply_hz"
"""The input column that sets the motor's supply frequency (Hz) when no [[input]] is declared."""

MOTOR_CHANNEL = "motor"
"""The default output channel of the motor node."""


@dataclass(frozen=True)
class OutputMap:
    """One output channel resolved onto the train.

    Attributes:
        channel: column name in the measurements.
        node: the node whose interval-mean speed the channel reads.
        unit: ``rpm``, ``rad/s``, ``rev/s`` or ``m/min``.
        diameter_mm: the roller diameter on that node (for ``m/min``), ``None`` if the node
            carries no roller (or rollers of different diameters).
    """

    channel: str
    node: str
    unit: str = "rpm"
    diameter_mm: float | None = None

    def from_rpm(self, rpm: np.ndarray) -> np.ndarray:
        """Convert node speeds in rpm to this channel's unit."""
        return convert_rpm(rpm, self.unit, self.diameter_mm)


def convert_rpm(rpm: np.ndarray, unit: str, diameter_mm: float | None = None) -> np.ndarray:
    """Speeds in rpm to ``unit``: rad/s = rpm * pi/30, rev/s = rpm/60, m/min = rpm * pi * d.

    Raises ValueError for an unknown unit or ``m/min`` without a diameter.
    """
    rpm = np.asarray(rpm, dtype=np.float64)
    if unit == "rpm":
        return rpm
    if unit == "rad/s":
        return rpm * (math.pi / 30.0)
    if unit == "rev/s":
        return rpm / 60.0
    if unit == "m/min":
        if diameter_mm is None:
            raise ValueError("m/min needs a roller diameter")
        return rpm * (math.pi * diameter_mm * 1e-3)
    raise ValueError(f"unknown unit {unit!r}; use one of {', '.join(OUTPUT_UNITS)}")


def input_channels(spec: TrainSpec) -> tuple[InputChannel, ...]:
    """The declared ``[[input]]`` tables, or the default: ``supply_hz`` drives the motor."""
    if spec.input:
        return tuple(spec.input)
    if spec.motor is None:
        return ()
    return (InputChannel(channel=DEFAULT_SUPPLY_CHANNEL, drives="supply_hz"),)


def default_outputs(spec: TrainSpec) -> tuple[OutputChannel, ...]:
    """Every roller by its roller name, every node by its node name, ``motor``; all rpm."""
    names: list[tuple[str, str]] = []
    by_name = {r.name: r.node for r in spec.roller}
    names += [(r, by_name[r]) for r in ROLLER_NAMES if r in by_name]
    names += [(n.name, n.name) for n in spec.inertia]
    if spec.motor is not None:
        names.append((MOTOR_CHANNEL, spec.motor.node))
    seen: set[str] = set()
    out = []
    for channel, node in names:
        if channel not in seen:
            seen.add(channel)
            out.append(OutputChannel(channel=channel, node=node))
    return tuple(out)


def output_channels(spec: TrainSpec) -> tuple[OutputMap, ...]:
    """The declared ``[[output]]`` tables (or the defaults), resolved onto nodes."""
    maps = []
    for out in spec.output or default_outputs(spec):
        node, diameter = output_target(spec, out.node)
        maps.append(OutputMap(out.channel, node, out.unit, diameter))
    return tuple(maps)


__all__ = [
    "DEFAULT_SUPPLY_CHANNEL",
    "MOTOR_CHANNEL",
    "OutputMap",
    "convert_rpm",
    "default_outputs",
    "input_channels",
    "output_channels",
    "output_target",
]
