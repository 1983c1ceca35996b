"""Time simulation of a drive train: numba RK4 (production) and SciPy DOP853 (reference).

Output is the **mean speed over each output interval** (angle increment / interval), what an
encoder counting pulses reports. Point samples would alias the 200-700 Hz mesh and chain
lines of the FA320A into the band below Nyquist.

Time base: recording starts at ``t_start_s`` (default 0); a settling run of ``settle_s``
precedes it (inputs held at their first values), so the recorded data start in steady state.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from scipy.integrate import solve_ivp

from drafttwin._constants import ROLLERS
from drafttwin._limits import check_rk4_steps, check_samples
from drafttwin.errors import ConfigError
from drafttwin.mechanics import kernel as K
from drafttwin.mechanics import reduced as R
from drafttwin.mechanics.assembly import (
    DriveTrain,
    chain_mean_radius_m,
    chain_pitch_radius_m,
    gear_base_radii_m,
)
from drafttwin.mechanics.components import Belt, ChainDrive, GearMesh, Shaft
from drafttwin.mechanics.kinematics import RPM, OperatingPoint, operating_point

ENERGY_NAMES = ("motor", "roller_loads", "bearings", "coupling_losses", "external")

STOPPED_SUPPLY_HZ = 0.5
"""Below this supply frequency (Hz) the machine counts as stopped and a simulation starts from
rest. A VFD does not start its output below its starting frequency (e.g. the "starting
frequency" parameter Pr. 13 of Mitsubishi FR inverters; 0.5 Hz is an assumed typical setting),
and a torque-balance operating point at a few rpm would sit inside the friction
regularisation of the rollers and bearings."""


def starts_at_rest(train: DriveTrain, t_s: float) -> bool:
    """True if a simulation starting at ``t_s`` (s) starts at standstill: the train has no motor,
    or the motor's supply at ``t_s`` is below :data:`STOPPED_SUPPLY_HZ`."""
    motor = train.spec.motor
    if motor is None:
        return True
    supply = motor.supply_hz if train.supply_hz is None else float(train.supply_hz.at(t_s))
    return supply < STOPPED_SUPPLY_HZ


@dataclass(frozen=True)
class SimulationResult:
    """Interval-mean speeds of every node and the integrated energy flows.

    Attributes:
        time_s: end of each output interval, s, shape ``(n,)``.
        node_rpm: interval-mean speed of each node, rpm, shape ``(n, nodes)``.
        point_rpm: instantaneous speed at each interval end, rpm (for aliasing studies only).
        energy_j: energy accumulators at each interval end, J, shape ``(n, 5)``, counted from
            the start of recording (see :data:`ENERGY_NAMES`).
        node_names: node names, columns of ``node_rpm``.
        rollers: roller name -> column in ``node_rpm``; ``motor_node``: the motor's column.
        dt_s: integration step used; ``wall_s``: wall-clock time of the integration;
        ``compile_s``: time to compile the kernel or load it from numba's cache (first call).
    """

    time_s: np.ndarray
    node_rpm: np.ndarray
    point_rpm: np.ndarray
    energy_j: np.ndarray
    node_names: tuple[str, ...]
    rollers: dict[str, int]
    motor_node: int
    dt_s: float
    wall_s: float
    compile_s: float = 0.0

    def roller_rpm(self, rollers: tuple[str, ...] = ROLLERS) -> np.ndarray:
        """Interval-mean roller speeds, rpm, shape ``(n, len(rollers))``."""
        return self.node_rpm[:, [self.rollers[r] for r in rollers]]

    @property
    def motor_rpm(self) -> np.ndarray:
        return self.node_rpm[:, self.motor_node]

    def to_frame(self) -> pd.DataFrame:
        """``time`` (s), one rpm column per roller (front, second, third, back), ``motor``."""
        cols = {"time": self.time_s}
        for r in ROLLERS:
            if r in self.rollers:
                cols[r] = self.node_rpm[:, self.rollers[r]]
        cols["motor"] = self.motor_rpm
        return pd.DataFrame(cols)

    def mean_power_w(self) -> dict[str, float]:
        """Mean power of each energy flow over the recording, W."""
        span = self.time_s[-1] - (self.time_s[0] - (self.time_s[1] - self.time_s[0]))
        return {n: float(self.energy_j[-1, k] / span) for k, n in enumerate(ENERGY_NAMES)}


def _initial_state(train: DriveTrain, op: OperatingPoint) -> np.ndarray:
    """Steady-speed state with static deflections from the transmitted torques."""
    n = len(train.node_names)
    tab = train.tables()
    nb, nm = tab.belt_i.shape[0], tab.motor_i.shape[0]
    y = np.zeros(2 * n + nb + 2 * nm + K.N_ENERGY)
    y[n : 2 * n] = op.node_speed_rad_s
    belt_row = {b.name: k for k, b in enumerate(train.spec.belt)}
    for e in train.edges:
        c, torque = e.coupling, op.transmitted[e.coupling.name]
        if isinstance(c, Shaft):
            sign = 1.0 if c.a == train.node_names[e.parent] else -1.0
            y[e.child] = y[e.parent] - torque / c.stiffness_nm_per_rad * sign
        elif isinstance(c, Belt):
            rb = c.driven_diameter_mm * 5e-4
            y[2 * n + belt_row[c.name]] = torque / rb / c.span_stiffness_n_per_m
            y[e.child] = y[e.parent] * e.ratio
        elif isinstance(c, GearMesh):
            rba, rbb = gear_base_radii_m(c)
            delta = torque / rbb / c.mesh_stiffness_n_per_m + 0.5e-6 * c.backlash_um
            y[e.child] = (rba * y[e.parent] - delta) / rbb
        else:
            rb = chain_pitch_radius_m(c.pitch_mm, c.driven_teeth)
            stretch = torque / rb / (2 * c.span_stiffness_n_per_m)
            y[e.child] = _chain_angle_for_feed(c, y[e.parent], stretch)
    y[2 * n + nb : 2 * n + nb + nm] = op.motor_torque_nm
    return y


def _start_state(train: DriveTrain, t0: float, from_rest: bool) -> np.ndarray:
    """Standstill if asked or if the train is stopped at ``t0``, else the operating point."""
    if from_rest or starts_at_rest(train, t0):
        return _rest_state(train)
    return _initial_state(train, operating_point(train, t=t0))


def _rest_state(train: DriveTrain) -> np.ndarray:
    tab = train.tables()
    n = len(train.node_names)
    return np.zeros(2 * n + tab.belt_i.shape[0] + 2 * tab.motor_i.shape[0] + K.N_ENERGY)


def _chain_angle_for_feed(c: ChainDrive, theta_driver: float, stretch: float) -> float:
    """Driven-sprocket angle whose chain feed trails the driver's by ``stretch`` (Newton)."""
    ra = chain_pitch_radius_m(c.pitch_mm, c.driver_teeth)
    rb = chain_pitch_radius_m(c.pitch_mm, c.driven_teeth)
    target = K._chain_feed(theta_driver, c.driver_teeth, c.pitch_mm * 1e-3, ra)[0] - stretch
    theta = target / chain_mean_radius_m(c.pitch_mm, c.driven_teeth)
    for _ in range(20):
        x, dx = K._chain_feed(theta, c.driven_teeth, c.pitch_mm * 1e-3, rb)
        theta -= (x - target) / dx
    return theta


def _integrator(train: DriveTrain, y_full: np.ndarray) -> tuple[Any, np.ndarray, tuple]:
    """Kernel, start state and its table arguments: the full train's, or the reduced
    train's (:mod:`drafttwin.mechanics.reduced`) when it carries a reduction."""
    if train.reduction is None:
        return K.integrate, y_full, train.tables().args()
    y, args = R.reduced_start(train, y_full)
    return R.integrate, y, args


def _grid(rate_hz: float, dt_s: float) -> tuple[int, float]:
    steps = max(1, math.ceil(1.0 / (rate_hz * dt_s) - 1e-9))
    return steps, 1.0 / (rate_hz * steps)


def simulate(
    train: DriveTrain,
    duration_s: float,
    *,
    output_rate_hz: float | None = None,
    dt_s: float | None = None,
    settle_s: float | None = None,
    t_start_s: float = 0.0,
    from_rest: bool = False,
    progress: Callable[[float], None] | None = None,
) -> SimulationResult:
    """Integrate the train with fixed-step RK4 and return interval-mean speeds.

    Args:
        duration_s: recorded machine time, s.
        output_rate_hz: output samples per second (default: the train's solver setting).
        dt_s: integration step, s (rounded down so a whole number of steps fills an interval).
        settle_s: machine time simulated and discarded before recording, s.
        t_start_s: time of the start of recording, s (inputs are functions of this time).
        from_rest: start at standstill, unloaded (e.g. a start-up), instead of at the
            torque-balance operating point with static preloads. A train without a motor, or
            whose supply at the start is below :data:`STOPPED_SUPPLY_HZ`, always starts at rest.
        progress: called with the machine seconds completed since the last call.
    """
    import time as _time

    solver = train.spec.solver
    rate = solver.output_rate_hz if output_rate_hz is None else output_rate_hz
    default_dt = solver.dt_s if train.reduction is None else train.reduction.dt_s
    settle = solver.settle_s if settle_s is None else settle_s
    # a run that would never end (dt 1e-12 s, an infinite duration) is refused at once
    check_samples(duration_s, rate, where="duration, output rate (--duration, --rate)")
    check_rk4_steps(duration_s, default_dt if dt_s is None else dt_s, settle_s=settle,
                    where="the RK4 step (--dt, solver dt_s)")  # fmt: skip
    steps, dt = _grid(rate, default_dt if dt_s is None else dt_s)
    n_out = int(round(duration_s * rate))
    if n_out < 1:
        raise ConfigError(
            f"duration {duration_s} s is shorter than one output interval at {rate} Hz",
            where="--duration",
            fix="simulate for at least one output interval",
        )
    t0 = t_start_s - settle
    integrate, y, args = _integrator(train, _start_state(train, t0, from_rest))
    start = _time.perf_counter()
    integrate(y.copy(), t0, dt, 1, 1, *args)  # compile / load from cache outside the timing
    compile_s = _time.perf_counter() - start
    start = _time.perf_counter()
    if settle > 0:
        n_settle = max(1, int(round(settle * rate)))
        integrate(y, t0, dt, n_settle, steps, *args)
        t0 += n_settle / rate
    y[-K.N_ENERGY :] = 0.0
    theta0 = y[: len(train.node_names)] if train.reduction is None else R.expand_angles(y, args)
    theta0 = theta0.copy()
    chunk = max(1, int(rate * 0.25))
    thetas, omegas, energies = [], [], []
    done = 0
    while done < n_out:
        m = min(chunk, n_out - done)
        th, om, en = integrate(y, t0 + done / rate, dt, m, steps, *args)
        thetas.append(th)
        omegas.append(om)
        energies.append(en)
        done += m
        if progress is not None:
            progress(m / rate)
    wall = _time.perf_counter() - start
    theta = np.vstack([theta0[None, :], *thetas])
    return SimulationResult(
        time_s=t0 + np.arange(1, n_out + 1) / rate,
        node_rpm=np.diff(theta, axis=0) * rate * RPM,
        point_rpm=np.vstack(omegas) * RPM,
        energy_j=np.vstack(energies),
        node_names=train.node_names,
        rollers=dict(train.roller_nodes),
        motor_node=train.node_index(train.spec.root_node),
        dt_s=dt,
        wall_s=wall,
        compile_s=compile_s,
    )


def simulate_reference(
    train: DriveTrain,
    duration_s: float,
    *,
    output_rate_hz: float | None = None,
    settle_s: float = 0.0,
    rtol: float = 1e-10,
) -> np.ndarray:
    """Interval-mean node speeds (rpm) from SciPy's DOP853: the reference for tests.

    Uses the same right-hand side as the RK4 kernel but adaptive, high-order stepping; slow
    (tens of seconds per simulated second), so keep runs short.
    """
    rate = train.spec.solver.output_rate_hz if output_rate_hz is None else output_rate_hz
    args = train.tables().args()
    n = len(train.node_names)
    t0 = -settle_s
    y0 = _start_state(train, t0, from_rest=False)

    def f(t: float, y: np.ndarray) -> np.ndarray:
        dy = np.empty_like(y)
        K.rhs(t, y, dy, *args)
        return dy

    n_out = int(round(duration_s * rate))
    t_eval = np.arange(n_out + 1) / rate
    sol = solve_ivp(f, (t0, t_eval[-1]), y0, method="DOP853", t_eval=t_eval, rtol=rtol,
                    atol=1e-12, max_step=2e-4)  # fmt: skip
    if not sol.success:
        raise RuntimeError(f"reference integration failed: {sol.message}")
    return np.diff(sol.y[:n].T, axis=0) * rate * RPM
