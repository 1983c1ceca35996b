"""A drive train stepped sample by sample while its supply set-point arrives live.

:func:`~drafttwin.mechanics.simulation.simulate` needs the whole VFD schedule in advance. A
live twin learns the set-point one sample at a time, so :class:`LiveStepper` keeps the
integrator state and advances it one output interval per call, the supply frequency ramping
linearly over the interval from the previous set-point sample to the new one (the same
linear interpolation :class:`~drafttwin.mechanics.assembly.Signal` applies offline). The
kernel reads the supply from the signal table on every RK4 stage, so the stepper rewrites
that table's two values in place before each call: no re-assembly per sample.

Outputs are interval-mean node speeds (angle increment over the interval), as an encoder and
:func:`simulate` report them. With a reduced train (:func:`~drafttwin.mechanics.reduce`) the
reduced kernel runs (about 65x faster on the FA320A).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from drafttwin.errors import ConfigError
from drafttwin.mechanics import kernel as K
from drafttwin.mechanics import reduced as R
from drafttwin.mechanics.assembly import DriveTrain, Signal
from drafttwin.mechanics.simulation import (
    NonFiniteSimulationError,
    _grid,
    _integrator,
)
from drafttwin.mechanics.start import _start_state
from drafttwin.mechanics.steady_state import RPM


class LiveStepper:
    """Step ``train`` one sample at a time, following a live supply set-point.

    Args:
        train: the drive train (reduced or full); it needs a motor.
        rate_hz: nominal sample rate, Hz (sets the RK4 step so whole steps fill a sample).
        supply_hz: the set-point at the start, Hz.
        t0_s: time of the first state, s (the train settles there first).
        settle_s: machine time simulated at the start set-point before ``t0_s``, s.
        dt_s: RK4 step, s (default: the train's, or the reduction's).
        run_up_s: if positive, the train starts at rest and its supply ramps from 0 to
            ``supply_hz`` over this time (s) before it settles, as a machine runs up; else it
            starts at the operating point.
    """

    def __init__(self, train: DriveTrain, rate_hz: float, supply_hz: float, *, t0_s: float = 0.0,
                 settle_s: float | None = None, dt_s: float | None = None,
                 run_up_s: float = 0.0) -> None:  # fmt: skip
        if train.spec.motor is None:
            raise ConfigError("a live twin follows the motor's supply set-point; the train has "
                              "no motor", source=train.source, where="[motor]",
                              fix="add a [motor] to the train")  # fmt: skip
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ConfigError(f"sample rate {rate_hz} Hz must be a positive number")
        self.rate_hz = float(rate_hz)
        self._sig = Signal(0.0, 1.0, np.array([supply_hz, supply_hz], dtype=np.float64))
        self.train = train.with_supply_schedule(self._sig)
        default_dt = train.spec.solver.dt_s if train.reduction is None else train.reduction.dt_s
        self.steps, self.dt_s = _grid(self.rate_hz, default_dt if dt_s is None else dt_s)
        settle = train.spec.solver.settle_s if settle_s is None else float(settle_s)
        run_up = max(0.0, float(run_up_s))
        y_full = _start_state(self.train, t0_s - settle - run_up, from_rest=run_up > 0)
        # the kernel's bundle; its arrays are read on every call, so writing into them (the
        # supply below, a plant's fault tables) changes what the next step integrates
        self._integrate, self.y, self._args = _integrator(self.train, y_full)
        self._kernel: Any = self._integrate  # the compiled overload once known (see _run)
        self._after: np.ndarray | None = None  # the angles of the state y, while it holds
        tab = self._tables
        self._sig_i, self._sig_f, self._sig_v = tab.sig_i, tab.sig_f, tab.sig_v
        k = self._motor_signal_index()
        self._start = int(self._sig_i[k, 0])
        self._k = k
        self.t_s = t0_s - settle - run_up
        self.supply_hz = float(supply_hz)
        if run_up > 0:
            self._run(run_up, 0.0, supply_hz)
        if settle > 0:
            self._run(t0_s - self.t_s, supply_hz, supply_hz)
        self.t_s = float(t0_s)
        self.node_names = train.node_names
        self.rollers = dict(train.roller_nodes)
        self.motor_node = train.node_index(train.spec.root_node)

    @property
    def _tables(self) -> K.TrainTables:
        """The element tables the kernel reads (a reduced train's remaining ones)."""
        model = self._args
        return model if isinstance(model, K.TrainTables) else model.tables

    def _motor_signal_index(self) -> int:
        """Row of the supply schedule in the kernel's signal table (the motor row names it)."""
        return int(self._tables.motor_i[0, 1])

    def _angles(self) -> np.ndarray:
        n = len(self.train.node_names)
        if isinstance(self._args, K.TrainTables):
            return self.y[:n].copy()
        return R.expand_angles(self.y, self._args)

    def _run(self, span_s: float, supply_from: float, supply_to: float) -> None:
        """Advance the state by ``span_s`` with the supply ramping linearly over it."""
        n_out = max(1, int(round(span_s * self.rate_hz)))
        span = n_out / self.rate_hz
        self._sig_f[self._k, 0] = self.t_s
        self._sig_f[self._k, 1] = span
        self._sig_v[self._start] = supply_from
        self._sig_v[self._start + 1] = supply_to
        args = (self.y, self.t_s, self.dt_s, n_out, self.steps, self._args)
        out = self._kernel(*args)
        if self._kernel is self._integrate:
            self._kernel = _compiled(self._integrate, args)
        self._after = None
        if not np.isfinite(out[1][-1]).all():
            raise NonFiniteSimulationError(
                f"the live physics produced a non-finite speed at t = {self.t_s + span:.6g} s",
                source=f"drive train {self.train.spec.train.name}",
                fix="check the set-point values the machine sends (supply_hz)",
            )
        self.t_s += span

    def step(self, supply_hz: float, span_s: float | None = None) -> np.ndarray:
        """Advance one interval (``span_s``, default one sample) while the supply ramps from
        the last set-point to ``supply_hz``; return the interval-mean node speeds, rpm."""
        span = 1.0 / self.rate_hz if span_s is None else float(span_s)
        before = self._angles() if self._after is None else self._after
        start = self.t_s
        self._run(span, self.supply_hz, float(supply_hz))
        self.supply_hz = float(supply_hz)
        self._after = after = self._angles()  # the next step's "before"
        rpm: np.ndarray = (after - before) / (self.t_s - start) * RPM
        return rpm

    def snapshot(self) -> tuple[np.ndarray, float, float]:
        """The state (copy), time and set-point: :meth:`restore` returns to it (a look-ahead
        step for a forecast is taken from a snapshot and undone)."""
        return self.y.copy(), self.t_s, self.supply_hz

    def restore(self, snap: tuple[np.ndarray, float, float]) -> None:
        self.y[:] = snap[0]
        self.t_s, self.supply_hz = snap[1], snap[2]
        self._after = None


def _compiled(dispatcher: Any, args: tuple[Any, ...]) -> Any:
    """The machine code numba compiled for ``args``' types, called without the dispatcher:
    it types every argument on every call, 5 of a reduced step's 16 us for the tables' tuple
    (measured). The types of a stepper's arguments never change. The dispatcher itself when
    numba does not offer it."""
    try:
        sig = tuple(dispatcher.typeof_pyval(a) for a in args)
        return dispatcher.overloads[sig].entry_point
    except (AttributeError, KeyError, TypeError):
        return dispatcher


__all__ = ["LiveStepper"]
