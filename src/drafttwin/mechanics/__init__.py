"""The mechanistic model: a lumped-parameter torsional drive-train simulation.

Public API::

    train = DriveTrain.preset("fa320a")          # or DriveTrain.from_toml(path)
    kin = kinematics(train)                      # nominal speeds, drafts, frequencies
    op = operating_point(train)                  # steady state from torque balance
    res = simulate(train, duration_s=10.0)       # numba RK4, interval-mean speeds
    res.to_frame()                               # time, front, second, third, back, motor
"""

from drafttwin.mechanics.assembly import DriveTrain, Signal
from drafttwin.mechanics.config import PRESETS, TrainSpec
from drafttwin.mechanics.kinematics import (
    Kinematics,
    OperatingPoint,
    eigenfrequencies_hz,
    kinematics,
    operating_point,
)
from drafttwin.mechanics.simulate import (
    SimulationResult,
    simulate,
    simulate_on_grid,
    simulate_reference,
)

__all__ = [
    "PRESETS",
    "DriveTrain",
    "Kinematics",
    "OperatingPoint",
    "Signal",
    "SimulationResult",
    "TrainSpec",
    "eigenfrequencies_hz",
    "kinematics",
    "operating_point",
    "simulate",
    "simulate_on_grid",
    "simulate_reference",
]
