"""Measured input channels on a time grid: what drives a train, what it outputs.

Each input channel mapped by the train (``[[input]]`` tables, by default a ``supply_hz``
column) becomes a time-varying VFD supply frequency or an external torque
(:func:`drive_from_inputs`); :func:`select_outputs` resolves the output channels asked for
onto nodes and units. :func:`~drafttwin.mechanics.simulation.simulate` with ``time_s`` uses both.

Time origin: the value at ``time_s[k]`` is the mean over ``(time_s[k] - T, time_s[k]]`` with
``T`` the grid step, so recording starts one step before ``time_s[0]``; inputs sampled on the
same grid become signals starting at ``time_s[0]`` and are held at their first value before it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from drafttwin.errors import ConfigError, DataError, unknown_choice
from drafttwin.mechanics.assembly import DriveTrain, Signal
from drafttwin.mechanics.channels import DEFAULT_SUPPLY_CHANNEL, OutputMap
from drafttwin.mechanics.components import OUTPUT_UNITS, InputChannel
from drafttwin.mechanics.config import M_PER_MIN_FIX, m_per_min_problem

InputColumns = Mapping[str, Any]
"""Input columns by name, each one value per time stamp (a dict of arrays, a DataFrame, ...)."""


GRID_JITTER = 0.01
"""How far (a share of the median step) a step of a simulated grid may be off it: the data
layer's rate tolerance."""


def grid_step_s(time_s: np.ndarray) -> float:
    """The step (s) of a uniform time grid; ConfigError if the grid is not uniform."""
    if time_s.ndim != 1 or len(time_s) < 2:
        raise DataError(
            f"a simulation on a time grid needs at least two time stamps, got {time_s.size}",
            where="time",
            fix="give the sample times of at least two samples",
        )
    steps = np.diff(time_s)
    step = float(np.median(steps))
    # a logger's clock jitter within the data layer's 1 % passes (the train is simulated on
    # the median step; 1 % of a step moves no roller speed measurably), and so do the
    # rounding steps of times stored as epoch seconds (about 2.4e-7 s at 1.7e9 s)
    tol = GRID_JITTER * step + 8 * float(np.spacing(np.max(np.abs(time_s))))
    if not step > 0 or np.max(np.abs(steps - step)) > tol:
        worst = int(np.argmax(np.abs(steps - step)))
        raise ConfigError(
            f"the simulation needs a uniform, increasing time grid: the step after sample "
            f"{worst + 1} is {steps[worst]:.6g} s against a median of {step:.6g} s (at most "
            f"{100 * GRID_JITTER:g} % off)",
            where="time",
            fix="resample the measurements to a regular grid first",
        )
    return step


def _input_values(
    item: InputChannel, inputs: InputColumns | None, time_s: np.ndarray, source: str
) -> np.ndarray:
    """The channel's samples with missing values filled by linear interpolation in time."""
    channel = item.channel
    if inputs is None or channel not in inputs:
        given = ", ".join(map(str, inputs)) if inputs is not None and len(inputs) else "none"
        raise DataError(
            f"the measurements have no input channel '{channel}', which drives the train's "
            f"{'motor supply' if item.drives == 'supply_hz' else f'node {item.node!r}'}",
            source=source,
            where=f"input '{channel}'",
            fix=f"add a '{channel}' column to the measurements or map an existing one in the "
            f"train's [[input]] table (input channels given: {given})",
        )
    try:
        values = np.asarray(inputs[channel], dtype=np.float64)
    except (TypeError, ValueError):
        values = np.empty(0)
    if values.shape != time_s.shape:
        raise DataError(
            f"input channel '{channel}' has {values.size} numeric values for {time_s.size} "
            "time stamps",
            where=f"input '{channel}'",
            fix="give one number per time stamp (NaN where a sample is missing)",
        )
    known = np.isfinite(values)
    if not known.any():
        raise DataError(
            f"input channel '{channel}' has no finite value",
            where=f"input '{channel}'",
            fix="record the channel, or drop its [[input]] table so the train does not need it",
        )
    if not known.all():  # a set-point is continuous in time: bridge gaps linearly
        values = np.interp(time_s, time_s[known], values[known])
    return values


def drive_from_inputs(
    train: DriveTrain, time_s: np.ndarray, inputs: InputColumns | None = None
) -> DriveTrain:
    """The train driven by its mapped input channels sampled on the grid ``time_s``.

    Each channel becomes ``gain * channel + offset`` as a :class:`Signal` (linear or
    zero-order hold) starting at ``time_s[0]``: the motor's supply schedule (clamped at 0 Hz:
    a VFD's frequency reference does not go negative; reversing needs a direction command) or
    an external torque on its node. Declared ``[[input]]`` channels are required; without
    declarations a missing ``supply_hz`` column leaves the motor at its configured constant
    ``supply_hz``.
    """
    time_s = np.asarray(time_s, dtype=np.float64)
    step = grid_step_s(time_s)
    t0 = float(time_s[0])
    driven = train
    for item in train.input_channels():
        default = not train.spec.input and item.channel == DEFAULT_SUPPLY_CHANNEL
        if default and (inputs is None or item.channel not in inputs):
            continue
        physical = item.gain * _input_values(item, inputs, time_s, train.source) + item.offset
        if item.drives == "supply_hz":
            signal = Signal(t0, step, np.maximum(physical, 0.0), item.hold)
            driven = driven.with_supply_schedule(signal)
        else:
            assert item.node is not None  # guaranteed by the config check
            driven = driven.with_torque(item.node, Signal(t0, step, physical, item.hold))
    return driven


def select_outputs(
    train: DriveTrain, channels: Sequence[str] | None, units: Mapping[str, str] | None
) -> list[OutputMap]:
    """The output maps of ``channels`` (default: all the train maps) with ``units`` applied;
    ConfigError for an unknown channel or unit, or ``m/min`` on a node without a roller."""
    available = {m.channel: m for m in train.output_channels()}
    names = list(available) if channels is None else [str(c) for c in channels]
    for name in names:
        if name not in available:
            raise unknown_choice(f"unknown output channel '{name}'", available,
                                 source=train.source, where="channels",
                                 fix_also=" (or map it in an [[output]] table)")  # fmt: skip
    units = dict(units or {})
    for name, unit in units.items():
        if name not in names:
            raise ConfigError(
                f"a unit is given for channel '{name}', which is not simulated",
                source=train.source,
                where="units",
                fix=f"give units only for the simulated channels: {', '.join(names)}",
            )
        if unit not in OUTPUT_UNITS:
            raise unknown_choice(f"unknown unit '{unit}' for channel '{name}'", OUTPUT_UNITS,
                                 source=train.source, where="units")  # fmt: skip
        if unit == "m/min" and available[name].diameter_mm is None:
            raise ConfigError(m_per_min_problem(available[name].node), source=train.source,
                              where=f"units['{name}']", fix=M_PER_MIN_FIX)  # fmt: skip
    return [replace(available[n], unit=units.get(n, available[n].unit)) for n in names]


def channel_values(
    train: DriveTrain, node_rpm: np.ndarray, maps: Sequence[OutputMap]
) -> np.ndarray:
    """The output channels ``maps`` from interval-mean node speeds (rpm, ``train``'s node
    order), shape ``(rows, len(maps))``, each in its unit."""
    columns = [m.from_rpm(node_rpm[:, train.node_index(m.node)]) for m in maps]
    return np.column_stack(columns) if columns else np.empty((len(node_rpm), 0))


__all__ = ["InputColumns", "channel_values", "drive_from_inputs", "grid_step_s", "select_outputs"]
