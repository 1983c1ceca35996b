"""Deprecated shortcuts for a simulation on a measurement time grid.

Use :func:`~drafttwin.mechanics.simulate.simulate` with ``time_s`` (and ``inputs``): it
returns a :class:`~drafttwin.mechanics.simulate.SimulationResult` like every simulation, whose
:meth:`~drafttwin.mechanics.simulate.SimulationResult.roller_rpm` and
:meth:`~drafttwin.mechanics.simulate.SimulationResult.channels` give the arrays these
shortcuts return. They stay, one line each, for the call sites that still use them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from drafttwin.mechanics.assembly import DriveTrain
from drafttwin.mechanics.inputs import InputColumns, drive_from_inputs, grid_step_s, select_outputs
from drafttwin.mechanics.simulate import SimulationResult, simulate


def simulate_channels(
    train: DriveTrain,
    time_s: np.ndarray,
    inputs: InputColumns | None = None,
    channels: Sequence[str] | None = None,
    units: Mapping[str, str] | None = None,
    **simulate_kwargs: Any,
) -> np.ndarray:
    """Deprecated: ``simulate(train, time_s=time_s, inputs=inputs).channels(channels, units)``
    (the channels are checked before the simulation runs, as there)."""
    select_outputs(train, channels, units)  # refuse an unknown channel before simulating
    res = simulate(train, time_s=time_s, inputs=inputs, **simulate_kwargs)
    return res.channels(channels, units)


def simulate_on_grid(
    train: DriveTrain, time_s: np.ndarray, inputs: InputColumns | None = None,
    **simulate_kwargs: Any,
) -> np.ndarray:  # fmt: skip
    """Deprecated: ``simulate(train, time_s=time_s, inputs=inputs).roller_rpm()``."""
    return simulate(train, time_s=time_s, inputs=inputs, **simulate_kwargs).roller_rpm()


def simulate_nodes_on_grid(
    train: DriveTrain, time_s: np.ndarray, inputs: InputColumns | None = None,
    **simulate_kwargs: Any,
) -> SimulationResult:  # fmt: skip
    """Deprecated: ``simulate(train, time_s=time_s, inputs=inputs)``."""
    return simulate(train, time_s=time_s, inputs=inputs, **simulate_kwargs)


__all__ = [
    "drive_from_inputs", "grid_step_s", "simulate_channels", "simulate_nodes_on_grid",
    "simulate_on_grid",
]  # fmt: skip
