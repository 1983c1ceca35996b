"""Assembly: a validated :class:`TrainSpec` becomes the numeric tables of the integrator.

:class:`DriveTrain` is the object users hold: built from a preset, a TOML file or a dict, it
knows its nodes, the spanning tree from the motor (for speed ratios and torque flow), and
compiles its components into the arrays :mod:`drafttwin.mechanics.kernel` integrates.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from drafttwin.errors import ConfigError
from drafttwin.mechanics import channels
from drafttwin.mechanics import kernel as K
from drafttwin.mechanics.channels import OutputMap
from drafttwin.mechanics.components import (
    BearingFriction,
    Belt,
    ChainDrive,
    DraftingZone,
    GearMesh,
    InputChannel,
    Roller,
    TorsionalCoupling,
)
from drafttwin.mechanics.config import TrainSpec, load_toml, preset_path, spec_from_dict

if TYPE_CHECKING:
    from drafttwin.mechanics.reduction import Reduction

Coupling = Belt | ChainDrive | GearMesh | TorsionalCoupling


@dataclass(frozen=True)
class Signal:
    """A time series on a uniform grid (linear interpolation, held constant outside it)."""

    t0_s: float
    dt_s: float
    values: np.ndarray
    hold: str = "linear"
    """``linear`` interpolation, or ``zoh``: each value held until the next sample."""

    @classmethod
    def from_samples(cls, times_s: Any, values: Any, max_dt_s: float = 1e-3) -> Signal:
        """Resample arbitrary increasing sample times onto a uniform grid."""
        times = np.asarray(times_s, dtype=np.float64)
        vals = np.asarray(values, dtype=np.float64)
        step = min(float(np.min(np.diff(times))), max_dt_s)
        n = int(math.ceil((times[-1] - times[0]) / step)) + 1
        grid = times[0] + step * np.arange(n)
        return cls(float(times[0]), step, np.interp(grid, times, vals))

    def at(self, time_s: Any) -> Any:
        """Value(s) at ``time_s`` (s), as the kernel evaluates it: linear or zero-order hold,
        held constant outside the grid."""
        u = np.clip(
            (np.asarray(time_s, dtype=np.float64) - self.t0_s) / self.dt_s, 0, len(self.values) - 1
        )
        if self.hold == "zoh":
            return self.values[(u + 1e-9).astype(np.int64).clip(max=len(self.values) - 1)]
        return np.interp(u, np.arange(len(self.values)), self.values)


@dataclass(frozen=True)
class Edge:
    """A coupling oriented away from the motor: ``parent`` drives ``child``."""

    kind: str
    coupling: Coupling
    parent: int
    child: int
    ratio: float  # child speed / parent speed (nominal, no creep)


def gear_base_radii_m(g: GearMesh) -> tuple[float, float]:
    cos_a = math.cos(math.radians(g.pressure_angle_deg))
    m = g.module_mm * 1e-3
    return 0.5 * m * g.driver_teeth * cos_a, 0.5 * m * g.driven_teeth * cos_a


def chain_pitch_radius_m(pitch_mm: float, teeth: int) -> float:
    return pitch_mm * 1e-3 / (2.0 * math.sin(math.pi / teeth))


def chain_mean_radius_m(pitch_mm: float, teeth: int) -> float:
    """Mean chain feed per radian, p z / (2 pi), slightly below the pitch radius."""
    return pitch_mm * 1e-3 * teeth / (2 * math.pi)


def mesh_stiffness_fourier(g: GearMesh) -> tuple[np.ndarray, np.ndarray]:
    """Cosine and sine coefficients (N/m) of the single/double-contact stiffness wave.

    A rectangular wave: double contact (``k_d``) for the fraction ``contact_ratio - 1`` of each
    mesh cycle, single contact (``k_s``) otherwise, mean ``mesh_stiffness_n_per_m``; truncated
    to ``harmonics`` terms with Lanczos sigma factors to tame the Gibbs overshoot.
    """
    w = g.contact_ratio - 1.0
    k_s = g.mesh_stiffness_n_per_m / ((1.0 - w) + w * g.stiffness_ratio)
    jump = (g.stiffness_ratio - 1.0) * k_s
    n = np.arange(1, g.harmonics + 1)
    sigma = np.sinc(n / (g.harmonics + 1))
    cos_c = sigma * jump * np.sin(2 * np.pi * n * w) / (np.pi * n)
    sin_c = sigma * jump * (1.0 - np.cos(2 * np.pi * n * w)) / (np.pi * n)
    return cos_c, sin_c


class Tables(K.TrainTables):
    """The element tables of a train: the fields and column layouts of
    :class:`drafttwin.mechanics.kernel.TrainTables`; :meth:`kernel` bundles them for the
    integrator (``_replace`` gives a copy with some tables changed)."""

    __slots__ = ()

    def args(self) -> tuple[np.ndarray, ...]:
        return tuple(self)

    def kernel(self) -> K.TrainTables:
        """The same arrays (not copies) as the kernels' one bundle."""
        return K.TrainTables(*self)


@dataclass(frozen=True)
class DriveTrain:
    """A drive train ready to analyse and simulate.

    Build it with :meth:`preset`, :meth:`from_toml` or :meth:`from_dict`. Time-varying inputs
    that do not belong in a config file (a VFD schedule, a drafting-force torque, rotor
    resistance drift) are attached with the ``with_*`` methods, which return a new train.
    """

    spec: TrainSpec
    source: str = "<dict>"
    supply_hz: Signal | None = None
    rotor_resistance: Signal | None = None
    torques: tuple[tuple[str, Signal], ...] = field(default=())
    reduction: Reduction | None = None
    """Set by :func:`drafttwin.mechanics.reduce`: simulate with stiff couplings rigid."""

    # ---- construction -------------------------------------------------------------------
    @classmethod
    def preset(cls, name: str) -> DriveTrain:
        path = preset_path(name)
        return cls(load_toml(path), source=f"preset '{name}'")

    @classmethod
    def from_toml(cls, path: str | Path) -> DriveTrain:
        return cls(load_toml(path), source=str(path))

    @classmethod
    def from_dict(cls, raw: dict[str, Any], source: str = "<dict>") -> DriveTrain:
        return cls(spec_from_dict(raw, source), source=source)

    def to_dict(self) -> dict[str, Any]:
        """The declaration as plain data (round-trips through :meth:`from_dict`); unset
        optional fields (an absent motor, a supply input's node) are left out, as in TOML."""
        return self.spec.model_dump(mode="json", exclude_none=True)

    def with_supply_schedule(self, signal: Signal) -> DriveTrain:
        """Supply (VFD set-point) frequency in Hz over time, replacing ``motor.supply_hz``."""
        return replace(self, supply_hz=signal)

    def with_rotor_resistance(self, signal: Signal) -> DriveTrain:
        """Rotor-resistance factor over time (1 = nominal); slip at a given torque scales with it."""
        return replace(self, rotor_resistance=signal)

    def with_torque(self, node: str, signal: Signal) -> DriveTrain:
        """Add an external torque (N m, positive drives the node) on ``node``."""
        self.node_index(node)
        return replace(self, torques=(*self.torques, (node, signal)))

    # ---- measured channels --------------------------------------------------------------
    def input_channels(self) -> tuple[InputChannel, ...]:
        """Measured input columns that drive the train: the ``[[input]]`` tables, or by
        default a ``supply_hz`` column (Hz) setting the motor's supply (none without a motor)."""
        return channels.input_channels(self.spec)

    def output_channels(self) -> tuple[OutputMap, ...]:
        """Measured output columns resolved onto nodes with their units: the ``[[output]]``
        tables, or by default every roller, every node and ``motor``, all in rpm."""
        return channels.output_channels(self.spec)

    # ---- topology -----------------------------------------------------------------------
    @cached_property
    def node_names(self) -> tuple[str, ...]:
        return tuple(n.name for n in self.spec.inertia)

    def node_index(self, name: str) -> int:
        try:
            return self.node_names.index(name)
        except ValueError:
            raise ConfigError(
                f"unknown node '{name}'",
                source=self.source,
                fix=f"use one of: {', '.join(self.node_names)}",
            ) from None

    @cached_property
    def inertias(self) -> np.ndarray:
        return np.array([n.inertia_kgm2 for n in self.spec.inertia])

    @cached_property
    def external_torques(self) -> tuple[tuple[int, Signal], ...]:
        """(node index, torque signal in N m) of every external torque: config series first."""
        from_config = [(self.node_index(t.node), Signal.from_samples(t.times_s, t.torque_nm))
                       for t in self.spec.torque]  # fmt: skip
        return (*from_config, *((self.node_index(n), s) for n, s in self.torques))

    @cached_property
    def roller_nodes(self) -> dict[str, int]:
        """Roller name (front, second, ...) to node index."""
        return {r.name: self.node_index(r.node) for r in self.spec.roller}

    @cached_property
    def edges(self) -> tuple[Edge, ...]:
        """Couplings in breadth-first order from the motor, oriented parent -> child."""
        adj: dict[int, list[tuple[str, Coupling, int, float]]] = {}
        for kind, c in self.spec.couplings():
            a, b = (self.node_index(x) for x in c.ends)
            r = c.speed_ratio
            adj.setdefault(a, []).append((kind, c, b, r))
            adj.setdefault(b, []).append((kind, c, a, 1.0 / r))
        root = self.node_index(self.spec.root_node)
        ratio = {root: 1.0}
        order: list[Edge] = []
        queue = deque([root])
        while queue:
            p = queue.popleft()
            for kind, c, q, r in adj.get(p, []):
                if q not in ratio:
                    ratio[q] = ratio[p] * r
                    order.append(Edge(kind, c, p, q, r))
                    queue.append(q)
                elif abs(ratio[q] - ratio[p] * r) > 1e-9 * ratio[q]:
                    raise ConfigError(
                        f"closes a loop with a speed ratio that contradicts the other path "
                        f"to node '{self.node_names[q]}'",
                        source=self.source,
                        where=f"{kind} '{c.name}'",
                        fix="a train may only close loops whose ratios agree; remove one path",
                    )
        return tuple(order)

    @cached_property
    def speed_ratios(self) -> np.ndarray:
        """Nominal speed of every node relative to the motor (rigid couplings, no creep)."""
        ratios = np.zeros(len(self.node_names))
        ratios[self.node_index(self.spec.root_node)] = 1.0
        for e in self.edges:
            ratios[e.child] = ratios[e.parent] * e.ratio
        return ratios

    # ---- numeric tables -----------------------------------------------------------------
    def _drafting_rows(self, idx: Callable[[str], int]) -> list[tuple[int, DragRow]]:
        rollers: dict[str, Roller] = {r.name: r for r in self.spec.roller}
        return [(idx(node), row) for z in self.spec.drafting_zone
                for node, row in _zone_rows(z, rollers)]  # fmt: skip

    def _effective_mass(self, a: int, b: int, ra: float, rb: float) -> float:
        ja, jb = self.inertias[a], self.inertias[b]
        mass: float = ja * jb / (ja * rb * rb + jb * ra * ra)
        return mass

    def _motor_rows(self, sig: Callable[[Signal | None], int]) -> tuple[np.ndarray, np.ndarray]:
        """Kernel rows of the induction motor (none for a train driven by external torques)."""
        mot = self.spec.motor
        if mot is None:
            return np.zeros((0, 3), dtype=np.int64), np.zeros((0, 6))
        w_rated = mot.rated_rpm * math.pi / 30.0
        w_sync_rated = 4.0 * math.pi * mot.rated_supply_hz / mot.poles
        lam = mot.breakdown_torque_ratio
        s_n = 1.0 - w_rated / w_sync_rated
        slip_k = s_n * (lam + math.sqrt(lam * lam - 1.0)) * w_sync_rated
        motor_i = np.array(
            [[self.node_index(mot.node), sig(self.supply_hz), sig(self.rotor_resistance)]],
            dtype=np.int64,
        )
        motor_f = np.array([[lam * mot.rated_power_w / w_rated, slip_k, mot.poles / 2,
                             mot.torque_lag_s, mot.torque_ripple, mot.supply_hz]])  # fmt: skip
        return motor_i, motor_f

    def tables(self) -> Tables:
        """Compile the components (cached per train; trains are immutable)."""
        return self._tables

    @cached_property
    def _tables(self) -> Tables:
        signals: list[Signal] = []

        def sig(s: Signal | None) -> int:
            if s is None:
                return -1
            signals.append(s)
            return len(signals) - 1

        idx = self.node_index
        motor_i, motor_f = self._motor_rows(sig)

        belts = [(idx(b.driver), idx(b.driven), b) for b in self.spec.belt]
        belt_i = np.array([[a, b_] for a, b_, _ in belts], dtype=np.int64).reshape(-1, 2)
        belt_f = np.zeros((len(belts), 5))
        for row, (a, b_, belt) in enumerate(belts):
            ra, rb = belt.driver_diameter_mm * 5e-4, belt.driven_diameter_mm * 5e-4
            c = (
                2
                * belt.damping_ratio
                * math.sqrt(belt.span_stiffness_n_per_m * self._effective_mass(a, b_, ra, rb))
            )
            belt_f[row] = (ra, rb, belt.span_stiffness_n_per_m, c, 1.0 / belt.axial_rigidity_n)

        chains = [(idx(c.driver), idx(c.driven), c) for c in self.spec.chain]
        chain_i = np.array([[a, b] for a, b, _ in chains], dtype=np.int64).reshape(-1, 2)
        chain_f = np.zeros((len(chains), 8))
        for row, (a, b, chain) in enumerate(chains):
            ra = chain_pitch_radius_m(chain.pitch_mm, chain.driver_teeth)
            rb = chain_pitch_radius_m(chain.pitch_mm, chain.driven_teeth)
            # both spans taut: stiffness 2k, so each span carries half the damping
            damp = chain.damping_ratio * math.sqrt(
                2 * chain.span_stiffness_n_per_m * self._effective_mass(a, b, ra, rb)
            )
            chain_f[row] = (chain.driver_teeth, chain.driven_teeth, chain.pitch_mm * 1e-3, ra, rb,
                            chain.span_stiffness_n_per_m, damp, chain.pretension_n)  # fmt: skip

        gears = [(idx(g.driver), idx(g.driven), g) for g in self.spec.gear]
        gear_i = np.array([[a, b, g.harmonics] for a, b, g in gears], dtype=np.int64).reshape(-1, 3)
        gear_f = np.zeros((len(gears), K.GEAR_COLS))
        for row, (a, b, g) in enumerate(gears):
            rba, rbb = gear_base_radii_m(g)
            damp = (
                2
                * g.damping_ratio
                * math.sqrt(g.mesh_stiffness_n_per_m * self._effective_mass(a, b, rba, rbb))
            )
            gear_f[row, : K.G_COEF] = (
                rba, rbb, g.driver_teeth, g.mesh_stiffness_n_per_m, damp, 0.5e-6 * g.backlash_um,
                1e-6 * g.driver_eccentricity_um, math.radians(g.driver_eccentricity_phase_deg),
                1e-6 * g.driven_eccentricity_um, math.radians(g.driven_eccentricity_phase_deg),
                1e-6 * g.transmission_error_um,
            )  # fmt: skip
            cos_c, sin_c = mesh_stiffness_fourier(g)
            gear_f[row, K.G_COEF : K.G_COEF + g.harmonics] = cos_c
            gear_f[row, K.G_COEF + K.NH_MAX : K.G_COEF + K.NH_MAX + g.harmonics] = sin_c

        # every torsional coupling declares its own row (shafts, then registered kinds)
        springs = [(idx(s.a), idx(s.b), s) for s in self.spec.springs()]
        spring_i = np.array([[a, b] for a, b, _ in springs], dtype=np.int64).reshape(-1, 2)
        spring_f = np.zeros((len(springs), 2))
        for row, (a, b, s) in enumerate(springs):
            spring_f[row] = s.spring_row(self.inertias[a], self.inertias[b])

        drags = [(idx(r.node), (r.friction_coefficient * 2 * r.top_load_per_side_n * r.diameter_mm * 5e-4,
                                r.friction_speed_eps_rad_s, 0.0, 0.0)) for r in self.spec.roller]  # fmt: skip
        drags += self._drafting_rows(idx)
        drags += [(idx(b.node), _bearing_row(b)) for b in self.spec.bearing]
        drag_i = np.array([[n] for n, _ in drags], dtype=np.int64).reshape(-1, 1)
        drag_f = np.array([row for _, row in drags], dtype=np.float64).reshape(-1, 4)

        ext = self.external_torques
        torque_i = np.array([[n, sig(s)] for n, s in ext], dtype=np.int64).reshape(-1, 2)
        torque_f = np.ones((len(ext), 1))

        starts = np.cumsum([0] + [len(s.values) for s in signals])
        sig_i = np.array(
            [[starts[k], len(s.values), int(s.hold == "zoh")] for k, s in enumerate(signals)],
            dtype=np.int64,
        ).reshape(-1, 3)
        sig_f = np.array([[s.t0_s, s.dt_s] for s in signals], dtype=np.float64).reshape(-1, 2)
        sig_v = np.concatenate([s.values for s in signals]) if signals else np.zeros(1)
        return Tables(1.0 / self.inertias, motor_i, motor_f, belt_i, belt_f,
                      chain_i, chain_f, gear_i, gear_f, spring_i, spring_f, drag_i, drag_f,
                      torque_i, torque_f, sig_i, sig_f, sig_v)  # fmt: skip


DragRow = tuple[float, float, float, float]  # coulomb torque, speed eps, viscous, kind


def _zone_rows(zone: DraftingZone, rollers: Mapping[str, Roller]) -> list[tuple[str, DragRow]]:
    """Two load rows: the force (N) at the delivering roller's radius brakes it, at the feeding
    roller's radius it drives it (a negative Coulomb torque)."""
    out: list[tuple[str, DragRow]] = []
    for name, sign in ((zone.delivering, 1.0), (zone.feeding, -1.0)):
        r = rollers[name]
        out.append(
            (r.node, (sign * zone.force_n * r.diameter_mm * 5e-4, zone.speed_eps_rad_s, 0.0, 0.0))
        )
    return out


def _bearing_row(b: BearingFriction) -> DragRow:
    return (b.coulomb_torque_nm, b.speed_eps_rad_s, b.viscous_nms, 1.0)
