"""Time simulation of a drive train: numba RK4 (production) and SciPy DOP853 (reference).

Output is the **mean speed over each output interval** (angle increment / interval), what an
encoder counting pulses reports. Point samples would alias the 200-700 Hz mesh and chain
lines of the FA320A into the band below Nyquist.

Time base: recording starts at ``t_start_s`` (default 0); a settling run of ``settle_s``
precedes it (inputs held at their first values), so the recorded data start in steady state.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
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
from drafttwin.mechanics.assembly import DriveTrain, Tables
from drafttwin.mechanics.inputs import (
    InputColumns,
    channel_values,
    drive_from_inputs,
    grid_step_s,
    select_outputs,
)
from drafttwin.mechanics.start import STOPPED_SUPPLY_HZ as STOPPED_SUPPLY_HZ
from drafttwin.mechanics.start import _start_state, starts_at_rest
from drafttwin.mechanics.start import static_angles as static_angles
from drafttwin.mechanics.steady_state import RPM

ENERGY_NAMES = ("motor", "roller_loads", "bearings", "coupling_losses", "external")
_Outputs = tuple[np.ndarray, np.ndarray, np.ndarray]
"""One kernel call's outputs: node angles, node speeds, energy accumulators (rows: times)."""


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
    train: DriveTrain | None = field(default=None, repr=False, compare=False)
    """The (driven) train simulated: :meth:`channels` reads its output channels."""

    def channels(
        self, channels: Sequence[str] | None = None, units: Mapping[str, str] | None = None
    ) -> np.ndarray:
        """The train's mapped output channels (default: all, see
        :meth:`~drafttwin.mechanics.assembly.DriveTrain.output_channels`), each in its unit
        or the one ``units`` names, shape ``(n, len(channels))``."""
        if self.train is None:
            raise ConfigError("this result does not carry its train",
                              fix="take it from simulate()")  # fmt: skip
        maps = select_outputs(self.train, channels, units)
        return channel_values(self.train, self.node_rpm, maps)

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


KernelModel = K.TrainTables | K.ReducedTables


def _integrator(train: DriveTrain, y_full: np.ndarray) -> tuple[Any, np.ndarray, KernelModel]:
    """Kernel, start state and the bundle it steps: the full train's tables, or the reduced
    train's (:mod:`drafttwin.mechanics.reduced`) when it carries a reduction."""
    if train.reduction is None:
        return K.integrate, y_full, train.tables().kernel()
    y, model = R.reduced_start(train, y_full)
    return K.integrate_reduced, y, model


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
        integrate, y, model = _integrator(train, _start_state(train, t0, self.from_rest))
        model = self._model_at(t0, model)
        start = _time.perf_counter()
        integrate(y.copy(), t0, dt, 1, 1, model)  # compile / load from cache outside the timing
        self.compile_s = _time.perf_counter() - start
        start = _time.perf_counter()
        if self.settle_s > 0:
            n_settle = self.settle_rows
            settled = integrate(y, t0, dt, n_settle, steps, model)
            self._check_finite(settled, t0, 0, settling=True)
            t0 += n_settle / rate
        y[-K.N_ENERGY :] = 0.0
        if isinstance(model, K.TrainTables):
            theta = y[: len(train.node_names)]
        else:
            theta = R.expand_angles(y, model)
        last_theta = theta.copy()
        block = self.block_rows
        pending: list[_Outputs] = []
        emitted = done = 0
        while done < self.n_rows:
            m = min(block, self.n_rows - done)
            model = self._model_at(t0 + done / rate, model)
            out = integrate(y, t0 + done / rate, dt, m, steps, model)
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

    def _model_at(self, t: float, model: KernelModel) -> KernelModel:
        """The kernel's tables for the block starting at ``t``: the train's own, or those of
        ``tables_at`` (parameters held constant over each block of :data:`BLOCK_S`)."""
        if self.tables_at is None:
            return model
        assert isinstance(model, K.TrainTables)  # refused for a reduced train in __init__
        new = self.tables_at(t).kernel()
        if any(a.shape != b.shape for a, b in zip(new, model, strict=True)):
            raise ConfigError("tables_at changed the shape of the train's tables",
                              fix="vary parameter values only, not elements")  # fmt: skip
        return new

    def _piece(
        self, pending: list[_Outputs], rows: int, first: int, t0: float, last_theta: np.ndarray
    ) -> tuple[SimulationPiece, list[_Outputs], np.ndarray]:
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

    def _check_finite(self, out: _Outputs, t0: float, first: int, *, settling: bool) -> None:
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
                fix=f"a smaller step (the drive train's [solver] dt_s, which 'simulate --dt' "
                f"sets; now {self.dt_s:.3g} s) keeps RK4 inside the "
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
    duration_s: float | None = None,
    *,
    time_s: Any = None,
    inputs: InputColumns | None = None,
    output_rate_hz: float | None = None,
    dt_s: float | None = None,
    settle_s: float | None = None,
    t_start_s: float | None = None,
    from_rest: bool | None = None,
    progress: Callable[[float], None] | None = None,
    tables_at: Callable[[float], Tables] | None = None,
    angles: bool = False,
) -> SimulationResult:
    """Integrate the train with fixed-step RK4 and return interval-mean speeds: for
    ``duration_s`` from ``t_start_s``, or on the measurement grid ``time_s`` driven by the
    recorded ``inputs`` (the one way to simulate; :func:`simulate_chunks` delivers the same
    run in pieces).

    Args:
        duration_s: recorded machine time, s (or give ``time_s``).
        time_s: a uniform measurement time grid, s: row ``k`` is the mean over
            ``(time_s[k] - T, time_s[k]]`` with ``T`` the grid step, which sets the output
            rate and the start of recording (so no ``output_rate_hz`` or ``t_start_s``).
        inputs: input columns on that grid (a dict of arrays, a DataFrame), mapped by the
            train's ``[[input]]`` tables (:func:`~drafttwin.mechanics.inputs.drive_from_inputs`);
            NaN bridged linearly in time. Without a supply column the motor runs at its
            configured ``supply_hz``.
        output_rate_hz: output samples per second (default: the train's solver setting).
        dt_s: integration step, s (rounded down so a whole number of steps fills an interval).
        settle_s: machine time simulated and discarded before recording, s.
        t_start_s: time of the start of recording, s (default 0; inputs are functions of
            this time).
        from_rest: start at standstill, unloaded (e.g. a start-up), instead of at the
            torque-balance operating point with static preloads. A train without a motor, or
            whose supply at the start is below :data:`STOPPED_SUPPLY_HZ`, always starts at rest
            (on a grid, with no settling run unless ``settle_s`` asks for one).
        progress: called with the machine seconds completed since the last call.
        tables_at: time-varying parameters (e.g. a growing fault): called with the start
            time of each kernel call (blocks of :data:`BLOCK_S`, and the settling run), it
            returns the tables to integrate that block with (same shapes as the train's).
        angles: also return the node angles at the start and every interval end
            (``angle_rad``); the other fields are the same either way.

    Raises:
        NonFiniteSimulationError: at the first NaN or infinite output (node and time named).
        ConfigError: neither or both of ``duration_s`` and ``time_s``; a non-uniform grid.
        DataError: a required input channel is missing, all-NaN or of the wrong length.
    """
    if (duration_s is None) == (time_s is None):
        raise ConfigError("give the simulation a duration or a time grid, one of the two",
                          where="duration_s, time_s",
                          fix="pass duration_s=SECONDS, or time_s=GRID with its inputs")  # fmt: skip
    if time_s is not None:
        if output_rate_hz is not None or t_start_s is not None:
            raise ConfigError("a time grid sets the output rate and the start of recording",
                              where="output_rate_hz, t_start_s",
                              fix="leave them out when giving time_s")  # fmt: skip
        time_s = np.asarray(time_s, dtype=np.float64)
        step = grid_step_s(time_s)
        train = drive_from_inputs(train, time_s, inputs)
        duration_s, output_rate_hz = len(time_s) * step, 1.0 / step
        t_start_s = float(time_s[0]) - step
        if from_rest is None:
            from_rest = starts_at_rest(train, t_start_s)
        if from_rest and settle_s is None:
            settle_s = 0.0  # nothing to settle: the recording starts at standstill
    elif inputs is not None:
        raise ConfigError("input columns need their time grid", where="inputs",
                          fix="pass time_s with the inputs")  # fmt: skip
    assert duration_s is not None
    stream = simulate_chunks(train, duration_s, chunk_s=math.inf, output_rate_hz=output_rate_hz,
                             dt_s=dt_s, settle_s=settle_s,
                             t_start_s=0.0 if t_start_s is None else t_start_s,
                             from_rest=bool(from_rest), progress=progress,
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
        train=train,
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


def reference_node_rpm(
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
    tab = train.tables().kernel()
    n = len(train.node_names)
    t0 = -settle_s
    y0 = _start_state(train, t0, from_rest=False)

    def f(t: float, y: np.ndarray) -> np.ndarray:
        dy = np.empty_like(y)
        K.rhs(t, y, dy, tab)
        return dy

    n_out = int(round(duration_s * rate))
    t_eval = np.arange(n_out + 1) / rate
    sol = solve_ivp(f, (t0, t_eval[-1]), y0, method="DOP853", t_eval=t_eval, rtol=rtol,
                    atol=1e-12, max_step=2e-4)  # fmt: skip
    if not sol.success:
        raise RuntimeError(f"reference integration failed: {sol.message}")
    rpm: np.ndarray = np.diff(sol.y[:n].T, axis=0) * rate * RPM
    return rpm
