"""The live hybrid of one machine: per sample, causally, clean -> physics -> hybrid -> row.

For each sample (in time order, see :class:`Reorder`):

1. **Cleaning** (:class:`SpikeFilter`): the paper's spike rule in its causal form
   (:func:`drafttwin.data.preprocessing.reject_spikes_causal`, same decisions sample by sample):
   a spike becomes missing and the models hold the last value.
2. **Physics**: the drive train (reduced by default) stepped one interval with the supply
   ramping from the last set-point sample to this one (:class:`~drafttwin.mechanics.stepper.LiveStepper`).
3. **Twin**: the model's prediction for this sample from earlier samples only and this
   sample's physics (the set-point arrives with the sample, so the physics at its time is
   known), through the one incremental predictor (:class:`~drafttwin.models.OnlinePredictor`);
   then the sample is observed. Horizons above one need the physics ``h`` samples ahead before
   their set-points arrive: a look-ahead step with the set-point held (undone before the next
   real step) stands in for it.

Missing samples between two received ones are observed as missing (NaN) so the predictor's
history keeps its time grid; a gap longer than ``max_fill_s`` restarts physics and predictor.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drafttwin.errors import ConfigError
from drafttwin.mechanics import DriveTrain, reduce
from drafttwin.mechanics.stepper import LiveStepper
from drafttwin.models import OnlinePredictor
from drafttwin.models.base import BaseModel
from drafttwin.models.mechanistic import MechanisticModel
from drafttwin.twin.store.db import EventRow, SampleRow

SPIKE_THRESHOLD = 0.10
"""The paper's outlier rule: 10 % from the last accepted sample."""


class SpikeFilter:
    """:func:`~drafttwin.data.preprocessing.reject_spikes_causal` one row at a time (relative
    rule with a floor per channel)."""

    def __init__(self, n: int, threshold: float = SPIKE_THRESHOLD,
                 floor: np.ndarray | None = None) -> None:  # fmt: skip
        self.threshold = threshold
        # Python floats, not NumPy scalars: a row of a few channels is cheaper in plain
        # arithmetic (the same IEEE doubles, so the same decisions)
        given = np.zeros(n) if floor is None else np.asarray(floor, dtype=np.float64)
        self.floor: list[float] = given.tolist()
        self.last = [math.nan] * n  # last accepted value per channel
        self.held = [math.nan] * n  # the sample rejected just before, if any
        self.rejected = 0

    def __call__(self, row: np.ndarray) -> np.ndarray:
        out: list[float] = np.asarray(row, dtype=np.float64).tolist()
        last_, held_, floor_ = self.last, self.held, self.floor
        for j, v in enumerate(out):
            if v != v:  # NaN
                continue
            last, held = last_[j], held_[j]
            tol = self.threshold * max(abs(last) if last == last else 0.0, floor_[j])
            moved = held == held and abs(v - held) <= tol
            if last == last and abs(v - last) > tol and not moved:
                held_[j], out[j] = v, math.nan
                self.rejected += 1
            else:
                last_[j], held_[j] = v, math.nan
        return np.array(out, dtype=np.float64)


@dataclass(order=True)
class Pending:
    ts_us: int
    seq: int = field(compare=False)
    values: np.ndarray = field(compare=False)
    setpoint: float = field(compare=False)
    received: float = field(compare=False, default=0.0)
    motor: float = field(compare=False, default=math.nan)


class Reorder:
    """Put rows back in time order: a row is released when it is the next one on the grid,
    or when ``depth`` later rows wait behind it (the missing ones are then a gap). Rows at or
    before the last released time are late or duplicates: counted and dropped."""

    def __init__(self, period_us: int, depth: int = 3) -> None:
        self.period_us, self.depth = period_us, depth
        self.heap: list[Pending] = []
        self.times: set[int] = set()
        self.last_us: int | None = None
        self.late = self.duplicate = 0

    def push(self, row: Pending) -> list[Pending]:
        if row.ts_us in self.times or row.ts_us == self.last_us:
            self.duplicate += 1
            return []
        if self.last_us is not None and row.ts_us < self.last_us:
            self.late += 1
            return []
        heapq.heappush(self.heap, row)
        self.times.add(row.ts_us)
        out = []
        while self.heap and (
            self.last_us is None
            or self.heap[0].ts_us - self.last_us <= self.period_us * 1.5
            or len(self.heap) > self.depth
        ):
            out.append(self._pop())
        return out

    def flush(self) -> list[Pending]:
        """Release everything held (the source went silent)."""
        return [self._pop() for _ in range(len(self.heap))]

    def _pop(self) -> Pending:
        row = heapq.heappop(self.heap)
        self.times.discard(row.ts_us)
        self.last_us = row.ts_us
        return row


def physics_train(model: BaseModel, physics: str) -> DriveTrain:
    """The drive train the model's mechanistic source names (a preset or a stored train)."""
    spec = getattr(model, "mechanistic_spec_", None) or {"kind": "preset", "name": "fa320a"}
    if spec.get("kind") == "preset":
        train = DriveTrain.preset(str(spec["name"]))
    elif spec.get("kind") == "train":
        train = DriveTrain.from_dict(dict(spec["spec"]), source=f"model file ({spec['name']})")
    else:
        raise ConfigError(
            f"the model's physics is {spec.get('kind')!r}: a live twin steps a drive train",
            fix="fit the model with --mechanistic preset or config:TRAIN.toml",
        )
    return reduce(train) if physics == "reduced" else train


@dataclass
class Begun:
    """A row between its physics step and its forecast (see :meth:`MachineTwin.receive_deferred`)."""

    twin: MachineTwin
    predictor: OnlinePredictor
    ts_us: int
    seq: int
    values: np.ndarray
    setpoint: float
    physics: np.ndarray
    motor: float = math.nan
    motor_physics: float = math.nan


class MachineTwin:
    """The live hybrid of one machine.

    Args:
        name: the machine's name.
        model: a fitted model (task ``prediction``, no exogenous inputs).
        train: the drive train to step (default: :func:`physics_train` of the model).
        rate_hz: the machine's sample rate, Hz.
        physics: ``reduced`` (default, fast) or ``full``.
        max_fill_s: longest gap observed as missing samples; a longer one restarts.
    """

    def __init__(self, name: str, model: BaseModel, rate_hz: float, *,
                 physics: str = "reduced", max_fill_s: float = 2.0,
                 train: DriveTrain | None = None) -> None:  # fmt: skip
        if physics not in ("reduced", "full"):
            raise ConfigError(f"physics {physics!r}", fix="use reduced or full")
        self.name, self.model, self.rate_hz = name, model, float(rate_hz)
        self.channels: tuple[str, ...] = tuple(model.channels_)
        self.period_us = int(round(1e6 / self.rate_hz))
        self.max_fill = int(max_fill_s * self.rate_hz)
        # machines sharing a model share its (immutable) train: reducing it takes a while
        self.train = train if train is not None else physics_train(model, physics)
        maps = {m.channel: m for m in self.train.output_channels()}
        missing = [c for c in self.channels if c not in maps]
        if missing:
            raise ConfigError(f"the drive train has no output channel(s) {missing}",
                              source=self.train.source,
                              fix="the model's channels must be outputs of its train")  # fmt: skip
        index = {n: i for i, n in enumerate(self.train.node_names)}
        self._maps = [(index[maps[c].node], maps[c]) for c in self.channels]
        self.horizon = int(model.task.horizon)
        self.reorder = Reorder(self.period_us)
        self.stepper: LiveStepper | None = None
        self.predictor: OnlinePredictor | None = None
        self._physics: dict[int, np.ndarray] = {}
        self._forecast: dict[int, np.ndarray] = {}
        self.filter = SpikeFilter(len(self.channels))
        self.events: list[EventRow] = []
        self.n_rows = 0
        self._fresh = True
        self.last_setpoint = math.nan
        self.last_us = 0

    # ---- physics as the predictor's mechanistic source ----------------------------------
    def _values_at(self, time_s: np.ndarray) -> np.ndarray:
        return np.array([self._physics[int(round(t * 1e6))] for t in np.atleast_1d(time_s)])

    def _to_channels(self, node_rpm: np.ndarray) -> np.ndarray:
        return np.array([m.from_rpm(node_rpm[i]) for i, m in self._maps], dtype=np.float64)

    def _start(self, ts_us: int, setpoint: float) -> None:
        """(Re)start physics and predictor at a sample: the train settles at its set-point."""
        # the physics runs on its own clock from 0 (epoch seconds would lose precision)
        self.stepper = LiveStepper(self.train, self.rate_hz, setpoint)
        self.last_us = ts_us - self.period_us
        mech = MechanisticModel(self._values_at, channels=self.channels, name="live physics")
        self.predictor = OnlinePredictor(self.model, mechanistic=mech)
        self._physics.clear()
        self._forecast.clear()
        self._fresh = True  # the spike filter's floor comes from the first physics row
        self.last_setpoint = setpoint

    def warm_up(self) -> None:
        """Load the compiled physics kernel and run the networks once, so the first live
        sample is not held up for a second (a source's queue could overflow meanwhile)."""
        nominal = self.train.spec.motor.supply_hz if self.train.spec.motor is not None else 50.0
        self._start(0, float(nominal))
        for k in range(self.horizon + 2):
            self._one(k * self.period_us, -1, np.full(len(self.channels), np.nan), float(nominal))
        self.stepper = self.predictor = None
        self.n_rows, self.events = 0, []

    # ---- per sample -----------------------------------------------------------------------
    def receive(self, ts_us: int, seq: int, values: np.ndarray, setpoint: float,
                received: float = 0.0, motor: float = math.nan) -> list[SampleRow]:  # fmt: skip
        """A sample from the source (any order); returns the rows it releases, in order."""
        rows = []
        for p in self.reorder.push(Pending(ts_us, seq, values, setpoint, received, motor)):
            rows += self._release(p)
        return rows

    def receive_deferred(self, ts_us: int, seq: int, values: np.ndarray, setpoint: float,
                         received: float = 0.0,
                         motor: float = math.nan) -> tuple[list[SampleRow], Begun | None]:  # fmt: skip
        """:meth:`receive`, but the last released row stops before its forecast: the caller
        forecasts many machines' rows in one network pass (:func:`forecast_many`) and ends each
        with :meth:`end`. Only for one-step models (else nothing is deferred)."""
        released = self.reorder.push(Pending(ts_us, seq, values, setpoint, received, motor))
        rows: list[SampleRow] = []
        for p in released[:-1]:
            rows += self._release(p)
        if not released:
            return rows, None
        more, begun = self._release(released[-1], defer=self.horizon == 1)
        return rows + more, begun

    def end(self, begun: Begun, twin: np.ndarray) -> SampleRow:
        """Finish a deferred row with its forecast."""
        return self._end(begun, twin)

    def flush(self) -> list[SampleRow]:
        rows = []
        for p in self.reorder.flush():
            rows += self._release(p)
        return rows

    def _release(self, p: Pending, defer: bool = False) -> Any:
        setpoint = p.setpoint if math.isfinite(p.setpoint) else self.last_setpoint
        if not math.isfinite(setpoint):
            return ([], None) if defer else []  # nothing drives the physics yet: wait
        last = None if self.stepper is None else self.last_us
        gap = 0 if last is None else int(round((p.ts_us - last) / self.period_us)) - 1
        if last is None or gap > self.max_fill or gap < 0:
            if last is not None:
                self.events.append(EventRow(self.name, "gap", p.ts_us,
                                            f"{gap} samples missing: physics and model restart"))  # fmt: skip
            self._start(p.ts_us, setpoint)
        rows = []
        if last is not None and 0 < gap <= self.max_fill:
            self.events.append(EventRow(self.name, "missing", p.ts_us, f"{gap} samples"))
            start = self.last_setpoint
            for k in range(1, gap + 1):  # observed as missing, the set-point ramped over them
                sp = start + (setpoint - start) * k / (gap + 1)
                nan = np.full(len(self.channels), np.nan)
                rows.append(self._one(last + k * self.period_us, -1, nan, sp))
        if defer:
            return rows, self._begin(p.ts_us, p.seq, p.values, setpoint, p.motor)
        rows.append(self._one(p.ts_us, p.seq, p.values, setpoint, p.motor))
        return rows

    def _one(self, ts_us: int, seq: int, values: np.ndarray, setpoint: float,
             motor: float = math.nan) -> SampleRow:  # fmt: skip
        begun = self._begin(ts_us, seq, values, setpoint, motor)
        if self.horizon == 1:  # this sample's set-point is known now: exact physics at t
            assert self.predictor is not None
            twin = self.predictor.forecast(ts_us / 1e6, begun.physics)
        else:
            twin = self._forecast.pop(ts_us, np.full(len(self.channels), np.nan))
        return self._end(begun, twin)

    def _begin(self, ts_us: int, seq: int, values: np.ndarray, setpoint: float,
               motor: float = math.nan) -> Begun:  # fmt: skip
        """Physics to this sample; the forecast comes next, then :meth:`_end`."""
        assert self.stepper is not None and self.predictor is not None
        node_rpm = self.stepper.step(setpoint, (ts_us - self.last_us) / 1e6)
        m = self._to_channels(node_rpm)
        self.last_setpoint, self.last_us = setpoint, ts_us
        self._physics[ts_us] = m
        if self._fresh:  # near standstill 10 % of the last value is nothing: floor it
            self.filter, self._fresh = SpikeFilter(len(self.channels), floor=0.5 * np.abs(m)), False
        return Begun(self, self.predictor, ts_us, seq, np.asarray(values, dtype=np.float64),
                     setpoint, m, motor, float(node_rpm[self.stepper.motor_node]))  # fmt: skip

    def _end(self, b: Begun, twin: np.ndarray) -> SampleRow:
        assert self.predictor is not None
        self.predictor.observe(b.ts_us / 1e6, self.filter(b.values), b.physics)
        if self.horizon > 1:
            self._look_ahead(b.ts_us, b.setpoint)
        else:
            self._physics.pop(b.ts_us - self.period_us, None)
        self.n_rows += 1
        return SampleRow(self.name, b.ts_us, b.seq, b.setpoint, b.values, b.physics, twin,
                         b.values - twin, b.motor, b.motor_physics)  # fmt: skip

    def _look_ahead(self, ts_us: int, setpoint: float) -> None:
        """Physics for the next ``horizon`` samples (set-point held) and the forecast of the
        sample ``horizon`` ahead; the stepper is put back afterwards."""
        assert self.stepper is not None and self.predictor is not None
        snap = self.stepper.snapshot()
        for k in range(1, self.horizon + 1):
            self._physics[ts_us + k * self.period_us] = self._to_channels(
                self.stepper.step(setpoint)
            )
        self.stepper.restore(snap)
        target = ts_us + self.horizon * self.period_us
        self._forecast[target] = self.predictor.forecast(target / 1e6)
        for old in [t for t in self._physics if t < ts_us - self.horizon * self.period_us * 4]:
            del self._physics[old]


__all__ = ["Begun", "MachineTwin", "Reorder", "SpikeFilter", "physics_train"]
