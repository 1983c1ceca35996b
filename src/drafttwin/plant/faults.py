"""Machine and sensor faults of the plant: what changes, from when, by how much.

A fault is ``element:kind`` with a severity (in the kind's own unit), an onset time and an
optional ramp (incipient growth: linear from 0 at onset to the full severity ``ramp_s``
later; 0 = an abrupt step)::

    FaultSpec.parse("E-F:wear:severity=60:onset=30:ramp=120")

Machine faults change physical parameters of the true drive train while the plant runs
(:class:`FaultSchedule` gives the kernel its tables block by block, see
:data:`drafttwin.mechanics.simulation.BLOCK_S`; the motor's rotor resistance and a roller's
load modulation are time signals). Sensor faults change only what an encoder reports; the
true speeds stay as they are. Every fault is recorded in the sidecar as a label.

Physical mapping of each kind (assumptions marked; docs/faults.md has the table):

* gear ``crack``: the pair's mesh stiffness falls by the fraction ``severity`` while one tooth
  of the driver gear is in mesh, once per driver revolution (window = contact ratio x pitch).
* gear ``wear``: uniform wear depth ``severity`` um on both working flanks: total backlash
  grows by 2 x depth; mean mesh stiffness falls by depth / (100 x module) (assumption: the
  loss grows in proportion to the wear depth, Chen et al. 2021, 10 % at 20 um on module 2).
* gear ``runout``: the driven gear's eccentricity grows by ``severity`` um (same phase).
* belt ``wear``: axial rigidity EA falls by the fraction ``severity`` (creep grows 1/(1-s)).
* chain ``elongation``: the loop grows by ``severity`` % of its length (assumption:
  :data:`CHAIN_LINKS` pitches): the pretension is lost and the spans go slack by half the
  extra length each (lost motion when the torque reverses).
* bearing ``bearing_friction`` on a node: Coulomb and viscous drag grow by the factor
  ``1 + severity``.
* roller ``load_loss``: the top-roller load (pressure arm) falls by the fraction ``severity``.
* roller ``eccentricity``: the once-per-revolution modulation of the roller's friction load
  grows by ``severity`` x its mean load (bottom-roller run-out, see plant effects); the
  roller's surface (:mod:`drafttwin.plant.surface`, only where a run asks for it) gets the
  radius eccentricity that goes with that load through the healthy roller's compliance,
  ``severity / roller_load_modulation x roller_eccentricity_um``.
* roller ``flute``: a damaged flute: over an arc of 1/20 of the circumference (at the
  roller's zero angle) the surface moves slower by the fraction ``severity``, once per
  revolution: a non-sinusoidal defect that leaves a comb of harmonics in the sliver. It acts
  on the roller's surface only (``drafttwin.plant.surface``), not on the drive train.
* motor ``rotor_resistance``: rotor resistance x (1 + severity) (on top of warm-up).
* motor ``torque_loss``: breakdown torque x (1 - severity).
* sensor ``gain`` (relative gain error), ``stuck`` (the channel repeats its value for
  ``severity`` s), ``dropout`` (a fraction ``severity`` of the channel's samples is lost).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping, Sequence
from typing import Annotated, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from drafttwin._constants import ROLLERS
from drafttwin.errors import ConfigError, unknown_choice
from drafttwin.mechanics import DriveTrain, Signal, operating_point
from drafttwin.mechanics import kernel as K
from drafttwin.mechanics.assembly import Tables
from drafttwin.mechanics.faults import CHAIN_LINKS as CHAIN_LINKS
from drafttwin.mechanics.faults import KINDS as KINDS
from drafttwin.mechanics.faults import (  # the catalogue and a fault's physics live there
    MACHINE_FAMILIES,
    slacken_chain,
    worn_stiffness_factor,
)
from drafttwin.mechanics.faults import SENSOR_CHANNELS as SENSOR_CHANNELS
from drafttwin.mechanics.faults import SURFACE_ONLY as SURFACE_ONLY
from drafttwin.mechanics.faults import FaultKind as FaultKind
from drafttwin.mechanics.faults import catalogue as catalogue
from drafttwin.mechanics.simulation import BLOCK_S


class FaultSpec(BaseModel):
    """One injected fault (validated; see the module docstring for each kind's meaning)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    element: Annotated[str, Field(min_length=1, max_length=100)]
    kind: Annotated[str, Field(min_length=1, max_length=40)]
    severity: float
    onset_s: Annotated[float, Field(ge=0, le=1e7)]
    ramp_s: Annotated[float, Field(ge=0, le=1e7)] = 0.0

    @property
    def spec_kind(self) -> FaultKind:
        return KINDS[self.kind]

    @property
    def is_sensor(self) -> bool:
        return self.spec_kind.family == "sensor"

    def profile(self, t: Any) -> np.ndarray:
        """Fraction of the full severity at times ``t`` (s): 0 before onset, then 1 (abrupt)
        or a linear ramp over ``ramp_s``."""
        t = np.asarray(t, dtype=np.float64)
        if self.ramp_s > 0:
            ramp: np.ndarray = np.clip((t - self.onset_s) / self.ramp_s, 0.0, 1.0)
            return ramp
        step: np.ndarray = (t >= self.onset_s).astype(np.float64)
        return step

    def label(self, block_s: float | None = None) -> dict[str, Any]:
        """The sidecar's record of this fault."""
        kind = self.spec_kind
        out: dict[str, Any] = {
            "element": self.element,
            "kind": self.kind,
            "family": kind.family,
            "severity": self.severity,
            "parameter": kind.parameter,
            "onset_s": self.onset_s,
            "ramp_s": self.ramp_s,
            "profile": "ramp" if self.ramp_s > 0 else "step",
        }
        if block_s is not None and not self.is_sensor and kind.name != "rotor_resistance":
            # machine parameters change at kernel-block boundaries (BLOCK_S)
            out["effective_onset_s"] = math.ceil(self.onset_s / block_s - 1e-9) * block_s
        return out

    @classmethod
    def parse(cls, text: str) -> FaultSpec:
        """``ELEMENT:KIND:severity=S:onset=T[:ramp=R]`` (the ``--fault`` syntax)."""
        parts = text.strip().split(":")
        fix = "write ELEMENT:KIND:severity=S:onset=T[:ramp=R], e.g. E-F:wear:severity=60:onset=30"
        if len(parts) < 3:
            raise ConfigError(f"cannot read fault '{text}'", where="--fault", fix=fix)
        values: dict[str, float] = {}
        for item in parts[2:]:
            m = re.fullmatch(r"\s*(severity|onset|ramp)\s*=\s*(\S+)\s*", item)
            if m is None:
                raise ConfigError(f"cannot read '{item}' in fault '{text}'", where="--fault",
                                  fix=fix)  # fmt: skip
            try:
                values[m.group(1)] = float(m.group(2))
            except ValueError:
                raise ConfigError(f"'{m.group(2)}' is not a number in fault '{text}'",
                                  where="--fault", fix=fix) from None  # fmt: skip
        missing = {"severity", "onset"} - set(values)
        if missing:
            raise ConfigError(f"fault '{text}' lacks {' and '.join(sorted(missing))}",
                              where="--fault", fix=fix)  # fmt: skip
        try:
            return cls(element=parts[0].strip(), kind=parts[1].strip(),
                       severity=values["severity"], onset_s=values["onset"],
                       ramp_s=values.get("ramp", 0.0))  # fmt: skip
        except ValidationError as exc:
            err = exc.errors()[0]
            field = str(err["loc"][0]) if err["loc"] else ""
            # the names the user typed (onset=, ramp=), not the model's (onset_s, ramp_s)
            typed = {"onset_s": "onset", "ramp_s": "ramp"}.get(field, field)
            got = f"={values[typed]:g}" if typed in values else ""
            msg = str(err["msg"]).replace("Input should be", "must be")
            raise ConfigError(f"fault '{text}': {typed}{got} {msg}", where="--fault",
                              fix=fix) from None  # fmt: skip


def check_faults(faults: Iterable[FaultSpec], train: DriveTrain) -> tuple[FaultSpec, ...]:
    """The faults, each checked against ``train`` (element, kind, severity range, ramp)."""
    cat = catalogue(train)
    out = []
    for f in faults:
        if f.element not in cat:
            raise unknown_choice(f"no element '{f.element}' can fail in {train.spec.train.name}",
                                 sorted(cat), where="--fault")  # fmt: skip
        if f.kind not in cat[f.element]:
            raise unknown_choice(f"'{f.element}' has no fault kind '{f.kind}'", cat[f.element],
                                 where="--fault")  # fmt: skip
        k = f.spec_kind
        low_ok = abs(f.severity) > 0 if k.signed else f.severity > k.low
        if not (low_ok and abs(f.severity) <= k.high):
            rng = (
                f"0 < |severity| <= {k.high:g}"
                if k.signed
                else f"{k.low:g} < severity <= {k.high:g}"
            )
            raise ConfigError(f"{f.element}:{f.kind} severity {f.severity:g} out of range "
                              f"({k.parameter})", where="--fault", fix=f"use {rng}")  # fmt: skip
        if f.ramp_s > 0 and not k.ramp_allowed:
            raise ConfigError(f"a {f.kind} fault has no ramp", where="--fault",
                              fix="leave out :ramp=")  # fmt: skip
        out.append(f)
    seen = [(f.element, f.kind) for f in out]
    if len(set(seen)) != len(seen):
        raise ConfigError("one element and kind named twice", where="--fault",
                          fix="give each ELEMENT:KIND once")  # fmt: skip
    return tuple(out)


def block_seconds(rate_hz: float) -> float:
    """Machine time over which the kernel holds parameters constant at ``rate_hz``."""
    return max(1, int(rate_hz * BLOCK_S)) / rate_hz


class FaultSchedule:
    """The kernel's tables at any time: the healthy tables with the machine faults applied.

    Args:
        train: the driven true train (signals attached): its tables are the healthy ones.
        faults: machine faults (sensor faults are ignored here).
    """

    def __init__(self, train: DriveTrain, faults: Sequence[FaultSpec]) -> None:
        self.train = train
        self.faults = tuple(f for f in faults if f.spec_kind.family in MACHINE_FAMILIES
                            and f.kind not in ("rotor_resistance", "eccentricity", "flute"))  # fmt: skip
        self.base = train.tables()
        self._cache: tuple[tuple[float, ...], Tables] | None = None

    def __call__(self, t: float) -> Tables:
        levels = tuple(float(f.severity * f.profile(t)) for f in self.faults)
        if self._cache is not None and self._cache[0] == levels:
            return self._cache[1]
        tables = self.base if not any(levels) else self.tables_for(levels)
        self._cache = (levels, tables)
        return tables

    def tables_for(self, levels: Sequence[float]) -> Tables:
        """Healthy tables with each fault at the given severity (its own unit)."""
        b = self.base
        gear_f, belt_f, chain_f = b.gear_f.copy(), b.belt_f.copy(), b.chain_f.copy()
        drag_f, motor_f = b.drag_f.copy(), b.motor_f.copy()
        spec = self.train.spec
        for f, s in zip(self.faults, levels, strict=True):
            if s == 0.0:
                continue
            if f.kind in ("crack", "wear", "runout"):
                row = [g.name for g in spec.gear].index(f.element)
                _gear_fault(gear_f[row], spec.gear[row], f.kind, s)
            elif f.kind == "belt_wear":
                belt_f[[b_.name for b_ in spec.belt].index(f.element), K.BELT_INV_EA] /= 1.0 - s
            elif f.kind == "elongation":
                row = [c.name for c in spec.chain].index(f.element)
                chain_f = slacken_chain(chain_f, row, s)
            elif f.kind == "bearing_friction":
                rows = (b.drag_i[:, 0] == self.train.node_index(f.element)) & (
                    b.drag_f[:, K.DR_KIND] == 1.0
                )
                drag_f[rows, K.DR_COUL] *= 1.0 + s
                drag_f[rows, K.DR_VISC] *= 1.0 + s
            elif f.kind == "load_loss":
                # roller rows come first in the drag table, in declaration order (assembly)
                row = [str(r.name) for r in spec.roller].index(f.element)
                drag_f[row, K.DR_COUL] *= 1.0 - s
            elif f.kind == "torque_loss":
                motor_f[:, K.MOT_TK] *= 1.0 - s
        return b._replace(gear_f=gear_f, belt_f=belt_f, chain_f=chain_f, drag_f=drag_f,
                          motor_f=motor_f)  # fmt: skip


def _gear_fault(row: np.ndarray, gear: Any, kind: str, s: float) -> None:
    """Apply a tooth fault to one gear table row (in place)."""
    if kind == "crack":
        row[K.G_CRACK] = s
        row[K.G_CRACK_ANGLE] = 0.0  # the cracked tooth sits at the driver's angle 0
        row[K.G_CRACK_SPAN] = gear.contact_ratio * 2 * math.pi / gear.driver_teeth
    elif kind == "wear":
        row[K.G_B] += 1e-6 * s  # half of the backlash growth 2 x depth
        factor = worn_stiffness_factor(s, gear.module_mm)
        row[K.G_K] *= factor
        row[K.G_COEF : K.G_CRACK] *= factor  # the stiffness wave scales with its mean
        row[K.G_C] *= math.sqrt(factor)  # c = 2 zeta sqrt(k m)
    else:
        row[K.G_EB] += 1e-6 * s


def rotor_resistance_signal(rotor: Signal, faults: Sequence[FaultSpec], step_s: float) -> Signal:
    """The warm-up rotor-resistance factor times each rotor fault's (1 + severity x profile),
    on a grid of ``step_s`` (an abrupt onset is resolved to ``step_s``)."""
    t = rotor.t0_s + step_s * np.arange(int(math.ceil((len(rotor.values) - 1) * rotor.dt_s
                                                      / step_s)) + 1)  # fmt: skip
    values = np.asarray(rotor.at(t), dtype=np.float64)
    for f in faults:
        values = values * (1.0 + f.severity * f.profile(t))
    return Signal(float(t[0]), step_s, values)


def eccentricity_torques(train: DriveTrain, faults: Sequence[FaultSpec], setpoint: Signal,
                         t0: float, t1: float, step_s: float, rng: np.random.Generator,
                         angle_at_start_rad: Mapping[str, float] | None = None,
                         ) -> tuple[dict[str, Signal], dict[str, float]]:  # fmt: skip
    """Extra once-per-revolution load torque of each faulty roller, N m (node -> signal), and
    the random phase (rad) drawn for each fault (roller name -> phase; one draw per fault, in
    order): the torque is ``-L severity profile(t) sin(2 pi cumsum(rev_hz) dt + phase + a)``
    with ``a`` the roller's angle at ``t0`` (``angle_at_start_rad``, 0 where not given)."""
    angles = angle_at_start_rad or {}
    op = operating_point(train)
    t = t0 + step_s * np.arange(int(math.ceil((t1 - t0) / step_s)) + 2)
    set_hz = np.asarray(setpoint.at(t), dtype=np.float64)
    speed_scale = set_hz / max(float(setpoint.values.max()), 1e-9)
    rollers = {str(r.name): r for r in train.spec.roller}
    out: dict[str, Signal] = {}
    phases: dict[str, float] = {}
    for f in faults:
        r = rollers[f.element]
        rev_hz = op.node_speed_rad_s[train.node_index(r.node)] / (2 * math.pi) * speed_scale
        phases[f.element] = float(rng.uniform(0, 2 * math.pi))
        start = phases[f.element] + angles.get(f.element, 0.0)
        phase = 2 * math.pi * np.cumsum(rev_hz) * step_s + start
        load = r.friction_coefficient * 2 * r.top_load_per_side_n * r.diameter_mm * 5e-4
        tq = -load * f.severity * f.profile(t) * np.sin(phase)
        out[r.node] = Signal(t0, step_s, tq)
    return out, phases


def apply_sensor_faults(rpm: np.ndarray, motor_rpm: np.ndarray, time_s: np.ndarray,
                        faults: Sequence[FaultSpec],
                        rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Measured roller speeds ``(n, 4)`` and motor speed ``(n,)`` as faulty encoders report
    them, and the roller samples a dropout removed (bool ``(n, 4)``)."""
    rpm, motor_rpm = rpm.copy(), motor_rpm.copy()
    dropped = np.zeros(rpm.shape, dtype=bool)
    for f in faults:
        if not f.is_sensor:
            continue
        col = SENSOR_CHANNELS.index(f.element)
        x = motor_rpm if col == len(ROLLERS) else rpm[:, col]
        p = f.profile(time_s)
        if f.kind == "gain":
            x *= 1.0 + f.severity * p
        elif f.kind == "stuck":
            active = (time_s >= f.onset_s) & (time_s < f.onset_s + f.severity)
            if active.any():
                first = int(np.argmax(active))
                held = x[: first + 1][np.isfinite(x[: first + 1])]
                value = held[-1] if held.size else np.nan
                x[active & np.isfinite(x)] = value
        else:
            lost = rng.random(len(time_s)) < f.severity * p
            x[lost] = np.nan
            if col < len(ROLLERS):
                dropped[:, col] |= lost
    return rpm, motor_rpm, dropped
