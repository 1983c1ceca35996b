"""The mechanistic model: a lumped-parameter torsional drive-train simulation.

Public API::

    train = DriveTrain.preset("fa320a")          # or DriveTrain.from_toml(path)
    kin = kinematics(train)                      # nominal speeds, drafts, frequencies
    op = operating_point(train)                  # steady state from torque balance
    res = simulate(train, duration_s=10.0)       # numba RK4, interval-mean speeds
    res.to_frame()                               # time, front, second, third, back, motor
    fast = simulate(reduce(train), 10.0)         # stiff couplings rigid: ~100x faster
    rec = simulate(train, time_s=time_s, inputs={"supply_hz": hz})  # on a measurement grid
    y = rec.channels(["front", "motor"])         # mapped output channels, in their units

``simulate`` is the one way to simulate (a duration or a measurement grid, always a
:class:`SimulationResult`); ``simulate_chunks`` gives the same run as a
:class:`SimulationStream` of pieces, so memory stays flat in the duration. (The tests'
reference integrator, SciPy's DOP853 on the same right-hand side, is
:func:`drafttwin.mechanics.simulation.reference_node_rpm`: no simulation of its own.)
"""

from drafttwin.mechanics.assembly import DriveTrain, Signal
from drafttwin.mechanics.channels import OutputMap, convert_rpm
from drafttwin.mechanics.components import InputChannel, OutputChannel
from drafttwin.mechanics.config import PRESETS, TrainSpec
from drafttwin.mechanics.inputs import drive_from_inputs
from drafttwin.mechanics.reduced import DEFAULT_CUTOFF_HZ, Reduction, reduce
from drafttwin.mechanics.simulation import (
    STOPPED_SUPPLY_HZ,
    NonFiniteSimulationError,
    SimulationPiece,
    SimulationResult,
    SimulationStream,
    simulate,
    simulate_chunks,
    static_angles,
)
from drafttwin.mechanics.start import starts_at_rest
from drafttwin.mechanics.steady_state import (
    Kinematics,
    OperatingPoint,
    eigenfrequencies_hz,
    kinematics,
    operating_point,
)

__all__ = [
    "DEFAULT_CUTOFF_HZ",
    "PRESETS",
    "STOPPED_SUPPLY_HZ",
    "DriveTrain",
    "InputChannel",
    "Kinematics",
    "NonFiniteSimulationError",
    "OperatingPoint",
    "OutputChannel",
    "OutputMap",
    "Reduction",
    "Signal",
    "SimulationPiece",
    "SimulationResult",
    "SimulationStream",
    "TrainSpec",
    "convert_rpm",
    "drive_from_inputs",
    "eigenfrequencies_hz",
    "kinematics",
    "operating_point",
    "reduce",
    "simulate",
    "simulate_chunks",
    "starts_at_rest",
    "static_angles",
]
