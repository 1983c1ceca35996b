"""The plant as a live machine: stepped in real time, its supply set-point changed while it
runs (``drafttwin plant serve`` publishes it over OPC UA or MQTT).

What it keeps of the recorded plant (:class:`~drafttwin.plant.Plant`): the machine's true
drive train (seeded parameter deviations, :class:`~drafttwin.plant.Machine`), encoders
counting whole edges over each sample window, dropped samples and spikes at the configured
rates. What it leaves out, because they are drawn over a whole record in advance: the
drafting-force noise, supply jitter, eccentricity torques and thermal drift. The VFD ramps its
output toward a written set-point at ``ramp_hz_per_s`` (an assumed acceleration setting).

Faults (``plant serve --fault``, the syntax of ``generate --fault``; onset and ramp in seconds
from the plant's start): machine faults change the true train's tables as the recorded plant's
:class:`~drafttwin.plant.faults.FaultSchedule` does (held per kernel block), written into the
running integrator; sensor faults change what the encoders report
(:func:`~drafttwin.plant.faults.apply_sensor_faults`). Not live: the rotor-resistance and
eccentricity faults (time signals drawn over a whole record) and machine faults on the reduced
physics (its tables are the reduction's).

**Computed ahead.** A sample is two parts: its physics (the VFD ramp, machine faults, one
kernel call: the true speeds) and its measurement (encoder edges, spikes, drops, sensor faults:
the random draws). :meth:`LivePlant.compute` does the first part for the next samples and keeps
them waiting; :meth:`LivePlant.step` measures the next one, computing it first if none waits.
A served plant computes up to a fraction of a second ahead in a worker thread
(:mod:`drafttwin.plant.serve.feed`; the kernel leaves the GIL while it integrates) and
publishes each sample at its wall-clock time. Each sample's physics is the same kernel call
whenever it runs, and the measurements draw in sample order, so the samples are the same bit
for bit however far ahead they were computed (and the same as stepping one by one); what
changes is when a written set-point takes effect: from the next sample computed, so up to the
look-ahead later.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from drafttwin._constants import ROLLERS
from drafttwin.errors import ConfigError
from drafttwin.mechanics import DriveTrain, reduce
from drafttwin.mechanics.stepper import LiveStepper
from drafttwin.plant.config import PlantConfig
from drafttwin.plant.faults import (
    SENSOR_CHANNELS,
    FaultSchedule,
    FaultSpec,
    apply_sensor_faults,
    block_seconds,
    check_faults,
)
from drafttwin.plant.machine import Machine
from drafttwin.plant.scenarios import RUN_UP_S

NOT_LIVE = ("rotor_resistance", "eccentricity")
"""Fault kinds the live plant cannot inject (time signals drawn for a whole record)."""

DEFAULT_RAMP_HZ_PER_S = 10.0
"""VFD acceleration/deceleration, Hz/s (assumption: 5 s from 0 to 50 Hz)."""
MAX_SUPPLY_HZ = 120.0
"""Highest set-point accepted, Hz (the FA320A motor is rated at 50 Hz)."""


@dataclass(frozen=True)
class LiveSample:
    """One published sample: counter, time (s), measured roller speeds (rpm, NaN dropped),
    measured motor speed (rpm) and the VFD output frequency (Hz)."""

    seq: int
    time_s: float
    rollers_rpm: np.ndarray
    motor_rpm: float
    supply_hz: float
    true_rpm: np.ndarray


def live_faults(faults: Sequence[FaultSpec], train: DriveTrain,
                physics: str = "full") -> tuple[FaultSpec, ...]:  # fmt: skip
    """The faults, checked for ``train`` and for what a live plant can inject."""
    checked = check_faults(faults, train)
    for f in checked:
        if f.kind in NOT_LIVE:
            raise ConfigError(f"a {f.kind} fault cannot be injected into the live plant",
                              where="--fault", fix="record it offline (drafttwin generate "
                              "--fault); live: a bearing, load, belt, gear, chain, torque or "
                              "sensor fault")  # fmt: skip
        if not f.is_sensor and physics != "full":
            raise ConfigError("machine faults need the full physics of the live plant",
                              where="--fault", fix="leave out --physics reduced")  # fmt: skip
    return checked


class LivePlant:
    """A drawing frame stepped one sample at a time.

    Args:
        seed: draws the machine (its true parameters) and the data-path defects.
        rate_hz: sample rate, Hz.
        t0_s: time of the first state, s (e.g. the epoch time when serving).
        physics: ``full`` (the truth, default) or ``reduced`` (for many machines on one core).
    """

    def __init__(self, seed: int = 0, rate_hz: float = 100.0, *, t0_s: float = 0.0,
                 train: DriveTrain | None = None, config: PlantConfig | None = None,
                 physics: str = "full", ramp_hz_per_s: float = DEFAULT_RAMP_HZ_PER_S,
                 faults: Sequence[FaultSpec] = ()) -> None:  # fmt: skip
        nominal = train if train is not None else DriveTrain.preset("fa320a")
        self.config = config if config is not None else PlantConfig()
        if nominal.spec.motor is None:
            raise ConfigError("the live plant follows the motor's supply; the train has none",
                              source=nominal.source, fix="add a [motor] to the train")  # fmt: skip
        self.machine = Machine.draw(nominal, self.config, seed)
        truth = reduce(self.machine.train) if physics == "reduced" else self.machine.train
        self.supply_hz = self.target_hz = float(nominal.spec.motor.supply_hz)
        self.ramp = float(ramp_hz_per_s)
        self.rate_hz = float(rate_hz)
        self.t0_s = float(t0_s)  # times are t0 + seq / rate: no round-off piling up
        run_up = RUN_UP_S if self.config.start == "run-up" else 0.0  # PlantConfig.start
        self.stepper = LiveStepper(truth, rate_hz, self.supply_hz, run_up_s=run_up)
        self._rollers = [int(truth.roller_nodes[r]) for r in ROLLERS]
        self._motor = self.stepper.motor_node
        s = self.config.sensors
        self._cpr = s.pulses_per_rev * s.quadrature
        self._rng = np.random.default_rng(np.random.SeedSequence([seed, 0x11FE]))
        self._rev = self._rng.uniform(0.0, 1.0, len(ROLLERS) + 1)  # arbitrary encoder zeros
        self._counts = np.floor(self._rev * self._cpr)
        self.seq = 0
        # the physics computed ahead of what is measured: (true speeds, supply) per sample
        self._computed = 0  # samples whose physics is done
        self._ramped_hz = self.supply_hz  # the VFD output at the last sample computed
        self._ahead: deque[tuple[np.ndarray, float]] = deque()
        # held while one sample's physics is computed (a worker's compute(), or step() or
        # skip() when nothing waits); the deque itself needs no lock (appends and pops are atomic)
        self._physics = threading.Lock()
        self._faults(live_faults(faults, nominal, physics), seed)

    def _faults(self, faults: tuple[FaultSpec, ...], seed: int) -> None:
        self.faults = faults
        self.sensor_faults = tuple(f for f in faults if f.is_sensor)
        machine = [f for f in faults if not f.is_sensor]
        self.schedule = FaultSchedule(self.stepper.train, machine) if machine else None
        self._block_s = block_seconds(self.rate_hz)
        self._held: dict[int, float] = {}  # stuck encoders: the value they repeat
        self._fault_rng = np.random.default_rng(np.random.SeedSequence([seed, 0xFA17]))

    def _apply_machine_faults(self, t: float) -> None:
        """Write the faulted tables (held per kernel block, as recorded) into the integrator."""
        assert self.schedule is not None
        args = self.stepper._args  # the kernel's table arrays, read on every call
        new = self.schedule(math.floor(t / self._block_s) * self._block_s).args()
        for old, value in zip(args[:-3], new[:-3], strict=True):  # the last three: the supply
            if old is not value and old.shape == value.shape:
                np.copyto(old, value)

    def _apply_sensor_faults(self, t: float, rollers: np.ndarray,
                             motor: float) -> tuple[np.ndarray, float]:  # fmt: skip
        x = np.append(rollers, motor)
        for f in self.sensor_faults:
            col = SENSOR_CHANNELS.index(f.element)
            if f.kind == "stuck":  # held at the value before onset for severity s
                if f.onset_s <= t < f.onset_s + f.severity:
                    x[col] = self._held.setdefault(col, x[col])
                continue
            r, m, _ = apply_sensor_faults(x[None, :4], x[4:], np.array([t]), [f],
                                          self._fault_rng)  # fmt: skip
            x[:4], x[4] = r[0], m[0]
        return x[:4], float(x[4])

    @property
    def revolutions(self) -> np.ndarray:
        """True revolutions of the rollers (front, second, third, back) and the motor since an
        arbitrary zero each (the encoders' own), exact at the last sample (or skip)."""
        return self._rev.copy()

    def set_supply(self, hz: float) -> None:
        """A new VFD set-point, Hz; the output ramps to it from the next sample computed."""
        if not (math.isfinite(hz) and 0.0 <= hz <= MAX_SUPPLY_HZ):
            raise ConfigError(f"supply set-point {hz!r} Hz", where="supply_setpoint_hz",
                              fix=f"write a number from 0 to {MAX_SUPPLY_HZ:g} Hz")  # fmt: skip
        self.target_hz = float(hz)

    @property
    def ahead(self) -> int:
        """Samples whose physics is computed and which are not measured yet."""
        return len(self._ahead)

    @property
    def computed(self) -> int:
        """Samples whose physics is computed (measured, skipped or waiting)."""
        return self._computed

    def compute(self, n: int = 1) -> None:
        """Compute the physics of the next ``n`` samples (they wait to be measured). Safe from
        a worker thread while the loop measures samples computed before."""
        for _ in range(n):
            with self._physics:
                self._advance()

    def _advance(self) -> None:
        """One sample's physics: ramp the supply, faults at the sample's time, integrate."""
        dt = 1.0 / self.rate_hz
        if self.schedule is not None:  # the expression stepping has always used
            self._apply_machine_faults((self._computed + 1) / self.rate_hz - dt)
        delta = self.target_hz - self._ramped_hz
        limit = self.ramp * dt if self.ramp > 0 else math.inf
        self._ramped_hz += max(-limit, min(limit, delta))
        node_rpm = self.stepper.step(self._ramped_hz)
        self._ahead.append((node_rpm[[*self._rollers, self._motor]], self._ramped_hz))
        self._computed += 1

    def skip(self, n: int) -> None:
        """Advance ``n`` samples, measuring none (a server that fell behind its clock catches
        up; the counter jumps by ``n``, which a twin counts as dropped samples). Samples
        computed ahead are dropped; the rest is integrated in one call. The encoders keep their
        position, so the next sample measures only its own window. The supply ramps linearly
        across that span (a set-point reached within it is spread over the whole span: an
        approximation of the catch-up only)."""
        if n <= 0:
            return
        dt = 1.0 / self.rate_hz
        with self._physics:
            for _ in range(min(n, len(self._ahead))):
                true, self.supply_hz = self._ahead.popleft()
                self._rev += true / 60.0 * dt
            rest = max(0, self.seq + n - self._computed)
            if rest:
                span = rest / self.rate_hz
                if self.schedule is not None:
                    self._apply_machine_faults(self._computed / self.rate_hz)
                delta = self.target_hz - self._ramped_hz
                limit = self.ramp * span if self.ramp > 0 else math.inf
                self._ramped_hz += max(-limit, min(limit, delta))
                node_rpm = self.stepper.step(self._ramped_hz, span_s=span)
                self._rev += node_rpm[[*self._rollers, self._motor]] / 60.0 * span
                self._computed += rest
                self.supply_hz = self._ramped_hz
        self._counts = np.floor(self._rev * self._cpr)
        self.seq += n

    def step(self) -> LiveSample:
        """The next sample: its physics (computed ahead, or now), its encoders' edges counted."""
        if not self._ahead:  # nothing computed ahead: wait for a sample being computed, or compute
            with self._physics:
                if not self._ahead:
                    self._advance()
        true, supply_hz = self._ahead.popleft()
        dt = 1.0 / self.rate_hz
        t_fault = (self.seq + 1) / self.rate_hz  # machine time of this sample, from the start
        self._rev += true / 60.0 * dt
        counts = np.floor(self._rev * self._cpr)
        measured = (counts - self._counts) / self._cpr * 60.0 / dt
        self._counts = counts
        s = self.config.sensors
        rollers = measured[:-1].copy()
        spikes = self._rng.random(len(rollers)) < s.outlier_rate
        if spikes.any():
            lo, hi = s.outlier_size
            size = lo + (hi - lo) * self._rng.random(len(rollers))
            sign = np.where(self._rng.random(len(rollers)) < 0.5, -1.0, 1.0)
            rollers = np.where(spikes, rollers * (1.0 + sign * size), rollers)
        motor = float(measured[-1])
        if self.sensor_faults:
            rollers, motor = self._apply_sensor_faults(t_fault, rollers, motor)
        if self._rng.random() < s.missing_rate:  # a dropped logger row
            rollers[:] = np.nan
            motor = math.nan
        self.seq += 1
        self.supply_hz = supply_hz
        time_s = self.t0_s + self.seq / self.rate_hz
        return LiveSample(self.seq, time_s, rollers, motor, supply_hz, true[:-1])


__all__ = ["DEFAULT_RAMP_HZ_PER_S", "LivePlant", "LiveSample", "live_faults"]
