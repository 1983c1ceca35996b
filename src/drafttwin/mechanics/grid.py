"""Simulation on a measurement time grid, driven by the machine's recorded input channels.

The physics follows what the machine was told to do: each input channel mapped by the train
(``[[input]]`` tables, by default a ``supply_hz`` column) becomes a time-varying VFD supply
frequency or an external torque, and the outputs are the interval means of the mapped nodes
over each sample interval, in each channel's unit.

Time origin: the value at ``time_s[k]`` is the mean over ``(time_s[k] - T, time_s[k]]`` with
``T`` the grid step, so recording starts one step before ``time_s[0]``; inputs sampled on the
same grid become signals starting at ``time_s[0]`` and are held at their first value before it.

Start: a train with a motor whose supply at the first sample is below
:data:`~drafttwin.mechanics.simulate.STOPPED_SUPPLY_HZ` (a stopped machine), and a train
without a motor, start from rest at the start of recording; otherwise the train starts at the
steady operating point of the first sample's inputs (the settle run holds them there).
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
from drafttwin.mechanics.simulate import SimulationResult, simulate, starts_at_rest

InputColumns = Mapping[str, Any]
"""Input columns by name, each one value per time stamp (a dict of arrays, a DataFrame, ...)."""


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
    if not step > 0 or np.max(np.abs(steps - step)) > 1e-6 * step + 1e-9:
        raise ConfigError(
            "the simulation needs a uniform, increasing time grid",
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


def _simulate_grid(train: DriveTrain, time_s: np.ndarray, **kwargs: Any) -> SimulationResult:
    """Interval means on the grid, with the start rule (rest or operating point) applied."""
    step = grid_step_s(time_s)
    t_start = float(time_s[0]) - step
    if "from_rest" not in kwargs:
        kwargs["from_rest"] = starts_at_rest(train, t_start)
    if kwargs["from_rest"] and "settle_s" not in kwargs:
        kwargs["settle_s"] = 0.0  # nothing to settle: the recording starts at standstill
    return simulate(train, duration_s=len(time_s) * step, output_rate_hz=1.0 / step,
                    t_start_s=t_start, **kwargs)  # fmt: skip


def _select_outputs(
    train: DriveTrain, channels: Sequence[str] | None, units: Mapping[str, str] | None
) -> list[OutputMap]:
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


def simulate_channels(
    train: DriveTrain,
    time_s: np.ndarray,
    inputs: InputColumns | None = None,
    channels: Sequence[str] | None = None,
    units: Mapping[str, str] | None = None,
    **simulate_kwargs: Any,
) -> np.ndarray:
    """Simulated output channels on a measurement time grid, driven by the input channels.

    Args:
        train: the drive train; its :meth:`~DriveTrain.input_channels` and
            :meth:`~DriveTrain.output_channels` say which columns drive it and what it outputs.
        time_s: uniform sample times (s); may start anywhere. Row ``k`` is the mean over the
            interval ``(time_s[k] - T, time_s[k]]``.
        inputs: input columns on the same grid (NaN filled by interpolation in time). Columns
            the train does not map are ignored.
        channels: output channels to return, in this order (default: all mapped outputs).
        units: per-channel unit overrides (``rpm``, ``rad/s``, ``rev/s``, ``m/min``).
        **simulate_kwargs: passed to :func:`~drafttwin.mechanics.simulate.simulate`
            (``dt_s``, ``settle_s``, ``from_rest`` to override the start rule, ...).

    Returns:
        Array of shape ``(len(time_s), len(channels))``, float64, in each channel's unit.

    Raises:
        DataError: a required input channel is missing, all-NaN or of the wrong length.
        ConfigError: an unknown output channel or unit, ``m/min`` on a non-roller, or a
            non-uniform time grid.
    """
    time_s = np.asarray(time_s, dtype=np.float64)
    maps = _select_outputs(train, channels, units)
    res = _simulate_grid(drive_from_inputs(train, time_s, inputs), time_s, **simulate_kwargs)
    columns = [m.from_rpm(res.node_rpm[:, train.node_index(m.node)]) for m in maps]
    return np.column_stack(columns) if columns else np.empty((len(time_s), 0))


def simulate_on_grid(
    train: DriveTrain,
    time_s: np.ndarray,
    inputs: InputColumns | None = None,
    **simulate_kwargs: Any,
) -> np.ndarray:
    """Roller speeds (rpm, columns front, second, third, back) on a measurement time grid.

    Each value is the mean over the sample interval that ends at that time stamp, as an
    encoder sampled on that grid reports it. The grid must be uniform. Inputs and the start
    rule are those of :func:`simulate_channels`; without inputs the motor runs at its
    configured ``supply_hz``.
    """
    time_s = np.asarray(time_s, dtype=np.float64)
    driven = drive_from_inputs(train, time_s, inputs)
    return _simulate_grid(driven, time_s, **simulate_kwargs).roller_rpm()


def simulate_nodes_on_grid(
    train: DriveTrain,
    time_s: np.ndarray,
    inputs: InputColumns | None = None,
    **simulate_kwargs: Any,
) -> SimulationResult:
    """The whole simulation result (every node's interval-mean speed) on a measurement grid,
    with the inputs and start rule of :func:`simulate_channels`."""
    time_s = np.asarray(time_s, dtype=np.float64)
    return _simulate_grid(drive_from_inputs(train, time_s, inputs), time_s, **simulate_kwargs)


__all__ = [
    "drive_from_inputs", "grid_step_s", "simulate_channels", "simulate_nodes_on_grid",
    "simulate_on_grid",
]  # fmt: skip
