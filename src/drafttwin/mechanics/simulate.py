"""Time simulation of a drive train: numba RK4 (production) and SciPy DOP853 (reference).

Output is the **mean speed over each output interval** (angle increment / interval), what an
encoder counting pulses reports. Point samples would alias the 200-700 Hz mesh and chain
lines of the FA320A into the band below Nyquist.

Time base: recording starts at ``t_start_s`` (default 0); a settling run of ``settle_s``
precedes it (inputs held at their first values), so the recorded data start in steady state.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from fractions import Fraction
from typing import Any

import numpy as np
import pandas as pd
from scipy.integrate import solve_ivp

from drafttwin._constants import ROLLERS
from drafttwin._limits import check_rk4_steps, check_samples
from drafttwin.errors import ConfigError, DrafttwinError
from drafttwin.mechanics import kernel as K
from drafttwin.mechanics import reduced as R
from drafttwin.mechanics.assembly import (
    DriveTrain,
    Tables,
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
        angle_rad: node angles, rad, shape ``(n + 1, nodes)``: row 0 at the start of
            recording, row ``i`` at the end of interval ``i`` (``node_rpm`` is
            :func:`interval_means` of it, bit for bit); None unless asked for (``angles``).
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
    angle_rad: np.ndarray | None = None

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


def static_angles(train: DriveTrain, chain_slack_m: dict[str, float] | None = None,
                  op: OperatingPoint | None = None) -> np.ndarray:  # fmt: skip
    """Node angles (rad, ``train.node_names`` order, motor rotor at 0) at the operating point:
    the static twist of shafts, belt stretch, mesh deflection plus half the backlash (the
    driven gear rests on its loaded flank) and chain stretch. ``chain_slack_m`` adds slack to
    named chains (an elongated chain's driven sprocket trails by half the extra loop length:
    the slack span takes up the other half). Diagnosis compares these between a train and the
    same train with a fault, e.g. a worn mesh's larger backlash. ``op``: the train's
    operating point if already at hand."""
    op = operating_point(train) if op is None else op
    return _initial_state(train, op, chain_slack_m)[: len(train.node_names)]


def _initial_state(train: DriveTrain, op: OperatingPoint,
                   chain_slack_m: dict[str, float] | None = None) -> np.ndarray:  # fmt: skip
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
            stretch += 0.5 * (chain_slack_m or {}).get(c.name, 0.0)
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


def interval_means(angle_rad: np.ndarray, rate_hz: float) -> np.ndarray:
    """Interval-mean speeds, rpm, shape ``(n, nodes)``, from the angles (rad) at the ``n + 1``
    ends of consecutive intervals of ``1 / rate_hz`` s: the simulator's own arithmetic."""
    return np.diff(angle_rad, axis=0) * rate_hz * RPM


class NonFiniteSimulationError(DrafttwinError):
    """A simulation produced NaN or an infinite value (an unstable step, implausible
    parameters): it stops at the first such output, naming the node and the time."""


@dataclass(frozen=True)
class SimulationPiece:
    """Consecutive output rows ``start_row .. start_row + len(time_s) - 1`` of a simulation
    (the fields as in :class:`SimulationResult`). ``angle_rad`` (only with ``angles``): node
    angles, rad, shape ``(rows + 1, nodes)``, row 0 at the piece's start (the previous
    piece's last row), so each piece's ``node_rpm`` is :func:`interval_means` of its own
    angles."""

    start_row: int
    time_s: np.ndarray
    node_rpm: np.ndarray
    point_rpm: np.ndarray
    energy_j: np.ndarray
    angle_rad: np.ndarray | None = None


BLOCK_S = 0.25
"""Machine time per kernel call, s. Calls always cut the record at multiples of this from its
start, whatever the pieces a caller asks for, so chunked and whole runs are bit-identical
(the kernel's time stamps are ``t0 + k * dt`` from each call's own start)."""


class SimulationStream:
    """A simulation delivered in pieces of about ``chunk_s`` of machine time, the full state
    carried from one piece to the next: concatenated, the pieces are bit-identical to
    :func:`simulate`'s arrays, while memory stays flat in the duration. See
    :func:`simulate_chunks` for the arguments; iterate to run it. ``node_names``,
    ``rollers``, ``motor_node``, ``dt_s``, ``n_rows`` describe the output; ``compile_s`` and
    ``wall_s`` are filled as it runs."""

    def __init__(self, train: DriveTrain, duration_s: float, *, chunk_s: float,
                 output_rate_hz: float | None, dt_s: float | None, settle_s: float | None,
                 t_start_s: float, from_rest: bool,
                 progress: Callable[[float], None] | None,
                 tables_at: Callable[[float], Tables] | None = None,
                 angles: bool = False) -> None:  # fmt: skip
        self.angles = angles
        solver = train.spec.solver
        if tables_at is not None and train.reduction is not None:
            raise ConfigError("time-varying parameters need the full train, not a reduced one",
                              fix="simulate the train without reduce()")  # fmt: skip
        self.tables_at = tables_at
        self.train = train
        self.rate_hz = solver.output_rate_hz if output_rate_hz is None else output_rate_hz
        default_dt = solver.dt_s if train.reduction is None else train.reduction.dt_s
        self.settle_s = solver.settle_s if settle_s is None else settle_s
        # a run that would never end (dt 1e-12 s, an infinite duration) is refused at once
        check_samples(duration_s, self.rate_hz, where="duration, output rate (--duration, --rate)")
        check_rk4_steps(duration_s, default_dt if dt_s is None else dt_s,
                        settle_s=self.settle_s, where="the RK4 step (--dt, solver dt_s)")  # fmt: skip
        self.steps, self.dt_s = _grid(self.rate_hz, default_dt if dt_s is None else dt_s)
        self.n_rows = int(round(duration_s * self.rate_hz))
        if self.n_rows < 1:
            raise ConfigError(
                f"duration {duration_s} s is shorter than one output interval at {self.rate_hz} Hz",
                where="--duration",
                fix="simulate for at least one output interval",
            )
        if not chunk_s > 0:
            raise ConfigError(f"chunk_s={chunk_s} is not > 0", fix="pieces of e.g. 60 s")
        whole = not math.isfinite(chunk_s) or chunk_s * self.rate_hz >= self.n_rows
        self.piece_rows = self.n_rows if whole else max(1, int(round(chunk_s * self.rate_hz)))
        self.t_start_s, self.from_rest, self.progress = t_start_s, from_rest, progress
        self.node_names = train.node_names
        self.rollers = dict(train.roller_nodes)
        self.motor_node = train.node_index(train.spec.root_node)
        self.compile_s = self.wall_s = 0.0

    def __iter__(self) -> Iterator[SimulationPiece]:
        import time as _time

        train, rate, dt, steps = self.train, self.rate_hz, self.dt_s, self.steps
        t0 = self.t_start_s - self.settle_s
        integrate, y, args = _integrator(train, _start_state(train, t0, self.from_rest))
        args = self._args_at(t0, args)
        start = _time.perf_counter()
        integrate(y.copy(), t0, dt, 1, 1, *args)  # compile / load from cache outside the timing
        self.compile_s = _time.perf_counter() - start
        start = _time.perf_counter()
        if self.settle_s > 0:
            n_settle = self.settle_rows
            settled = integrate(y, t0, dt, n_settle, steps, *args)
            self._check_finite(settled, t0, 0, settling=True)
            t0 += n_settle / rate
        y[-K.N_ENERGY :] = 0.0
        theta = y[: len(train.node_names)] if train.reduction is None else R.expand_angles(y, args)
        last_theta = theta.copy()
        block = self.block_rows
        pending: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        emitted = done = 0
        while done < self.n_rows:
            m = min(block, self.n_rows - done)
            args = self._args_at(t0 + done / rate, args)
            out = integrate(y, t0 + done / rate, dt, m, steps, *args)
            self._check_finite(out, t0, done, settling=False)
            pending.append(out)
            done += m
            while done - emitted >= self.piece_rows or (done == self.n_rows > emitted):
                rows = min(self.piece_rows, done - emitted)
                piece, pending, last_theta = self._piece(pending, rows, emitted, t0, last_theta)
                emitted += rows
                self.wall_s = _time.perf_counter() - start
                yield piece
            if self.progress is not None:
                self.progress(m / rate)
        self.wall_s = _time.perf_counter() - start

    @property
    def settle_rows(self) -> int:
        """Output intervals of the settling run (one kernel call; 0 without settling)."""
        return max(1, int(round(self.settle_s * self.rate_hz))) if self.settle_s > 0 else 0

    @property
    def block_rows(self) -> int:
        """Output rows per kernel call (:data:`BLOCK_S` of machine time)."""
        return max(1, int(self.rate_hz * BLOCK_S))

    def _args_at(self, t: float, args: tuple) -> tuple:
        """The kernel's tables for the block starting at ``t``: the train's own, or those of
        ``tables_at`` (parameters held constant over each block of :data:`BLOCK_S`)."""
        if self.tables_at is None:
            return args
        new = self.tables_at(t).args()
        if any(a.shape != b.shape for a, b in zip(new, args, strict=True)):
            raise ConfigError("tables_at changed the shape of the train's tables",
                              fix="vary parameter values only, not elements")  # fmt: skip
        return new

    def _piece(self, pending: list, rows: int, first: int, t0: float, last_theta: np.ndarray):
        """The first ``rows`` pending outputs as a piece; the rest stay pending."""
        th, om, en = (np.vstack([p[k] for p in pending]) for k in range(3))
        rest = [(th[rows:], om[rows:], en[rows:])] if len(th) > rows else []
        theta = np.vstack([last_theta[None, :], th[:rows]])
        piece = SimulationPiece(
            start_row=first,
            time_s=t0 + np.arange(first + 1, first + rows + 1) / self.rate_hz,
            node_rpm=interval_means(theta, self.rate_hz),
            point_rpm=om[:rows] * RPM,
            energy_j=en[:rows],
            angle_rad=theta if self.angles else None,
        )
        return piece, rest, th[rows - 1].copy()

    def _check_finite(self, out: tuple, t0: float, first: int, *, settling: bool) -> None:
        """Stop at the first non-finite output: the node (or energy flow) and the time."""
        for values, names, what in ((out[0], self.node_names, "angle"),
                                    (out[1], self.node_names, "speed"),
                                    (out[2], ENERGY_NAMES, "energy")):  # fmt: skip
            bad = ~np.isfinite(values)
            if not bad.any():
                continue
            row, col = (int(i) for i in np.argwhere(bad)[0])
            t = t0 + (first + row + 1) / self.rate_hz
            when = f"while settling, at t = {t:.6g} s" if settling else f"at t = {t:.6g} s"
            raise NonFiniteSimulationError(
                f"the simulation produced {values[row, col]} {when}: {what} of "
                f"{'energy flow' if what == 'energy' else 'node'} '{names[col]}'",
                source=f"drive train {self.train.spec.train.name}",
                fix=f"a smaller step (--dt; now {self.dt_s:.3g} s) keeps RK4 inside the "
                "stability limit of the stiffest coupling; else check that component's "
                "parameters",
            )


def simulate_chunks(
    train: DriveTrain,
    duration_s: float,
    *,
    chunk_s: float = 60.0,
    output_rate_hz: float | None = None,
    dt_s: float | None = None,
    settle_s: float | None = None,
    t_start_s: float = 0.0,
    from_rest: bool = False,
    progress: Callable[[float], None] | None = None,
    tables_at: Callable[[float], Tables] | None = None,
    angles: bool = False,
) -> SimulationStream:
    """:func:`simulate` in pieces of ``chunk_s`` machine seconds (the last one shorter):
    iterate the returned stream for :class:`SimulationPiece` s. Memory holds one piece, so a
    run of hours takes no more than one of a minute; the pieces join bit-identically to one
    long run. ``angles``: each piece also carries its node angles (``angle_rad``, its first
    row repeating the previous piece's last). Raises :class:`NonFiniteSimulationError` at the
    first NaN or infinity."""
    return SimulationStream(train, duration_s, chunk_s=chunk_s, output_rate_hz=output_rate_hz,
                            dt_s=dt_s, settle_s=settle_s, t_start_s=t_start_s,
                            from_rest=from_rest, progress=progress,
                            tables_at=tables_at, angles=angles)  # fmt: skip


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
    tables_at: Callable[[float], Tables] | None = None,
    angles: bool = False,
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
        tables_at: time-varying parameters (e.g. a growing fault): called with the start
            time of each kernel call (blocks of :data:`BLOCK_S`, and the settling run), it
            returns the tables to integrate that block with (same shapes as the train's).
        angles: also return the node angles at the start and every interval end
            (``angle_rad``); the other fields are the same either way.

    Raises:
        NonFiniteSimulationError: at the first NaN or infinite output (node and time named).
    """
    stream = simulate_chunks(train, duration_s, chunk_s=math.inf, output_rate_hz=output_rate_hz,
                             dt_s=dt_s, settle_s=settle_s, t_start_s=t_start_s,
                             from_rest=from_rest, progress=progress,
                             tables_at=tables_at, angles=angles)  # fmt: skip
    pieces = list(stream)
    return SimulationResult(
        time_s=np.concatenate([p.time_s for p in pieces]),
        node_rpm=np.vstack([p.node_rpm for p in pieces]),
        point_rpm=np.vstack([p.point_rpm for p in pieces]),
        energy_j=np.vstack([p.energy_j for p in pieces]),
        node_names=stream.node_names,
        rollers=stream.rollers,
        motor_node=stream.motor_node,
        dt_s=stream.dt_s,
        wall_s=stream.wall_s,
        compile_s=stream.compile_s,
        angle_rad=_joined_angles(pieces) if angles else None,
    )


def _joined_angles(pieces: list[SimulationPiece]) -> np.ndarray:
    """The pieces' angles as one array, each shared boundary row once."""
    angles = [p.angle_rad for p in pieces if p.angle_rad is not None]
    return np.vstack([angles[0], *(a[1:] for a in angles[1:])])


def decimation_factor(coarse: SimulationStream, fine: SimulationStream) -> int | None:
    """``m`` if every ``m``-th output row of ``fine`` comes from exactly the RK4 arithmetic of
    ``coarse``'s rows (so its angles there, and the interval means of them at ``coarse``'s
    rate, are bit-identical), else None. Both must be the same train, start, settling and
    tables; what is checked is the grid: ``fine``'s rate is ``m`` times ``coarse``'s exactly,
    with the same RK4 step, ``m`` times fewer steps per output, ``m`` times the rows, the
    settling run and the kernel calls (:data:`BLOCK_S`) cut at the same instants, so every
    kernel call starts at the same time stamp and takes the same steps."""
    ratio = Fraction(fine.rate_hz) / Fraction(coarse.rate_hz)
    if ratio.denominator != 1 or ratio < 1:
        return None
    m = int(ratio)
    same = (
        fine.dt_s == coarse.dt_s
        and fine.steps * m == coarse.steps
        and fine.n_rows == m * coarse.n_rows
        and fine.settle_rows == m * coarse.settle_rows
        and fine.block_rows == m * coarse.block_rows
        and fine.settle_s == coarse.settle_s
        and fine.t_start_s == coarse.t_start_s
    )
    return m if same else None


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
