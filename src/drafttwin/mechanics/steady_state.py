"""Kinematics and steady state without time integration.

* :func:`kinematics`: nominal roller speeds from tooth counts and diameters, surface speeds,
  zone drafts, delivery speed, excitation frequencies and torsional eigenfrequencies.
* :func:`operating_point`: the steady running state from torque balance alone: load torques
  reflected to the motor, the Kloss curve solved for slip, belt creep from the belt pull.
  It is independent of the integrator, so the simulation can be checked against it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy.linalg import eigh

from drafttwin.errors import ConfigError
from drafttwin.mechanics.assembly import (
    DriveTrain,
    Signal,
    chain_mean_radius_m,
    chain_pitch_radius_m,
    gear_base_radii_m,
)
from drafttwin.mechanics.components import Belt, ChainDrive, TorsionalCoupling

RPM = 30.0 / math.pi  # rad/s -> rpm


@dataclass(frozen=True)
class RollerKinematics:
    rpm: float
    diameter_mm: float
    surface_speed_m_min: float


@dataclass(frozen=True)
class Kinematics:
    """Nominal (rigid, no slip, no creep) kinematics at a given motor speed."""

    motor_rpm: float
    rollers: dict[str, RollerKinematics]
    delivery_speed_m_min: float
    drafts: dict[str, float]
    mesh_frequencies_hz: dict[str, float]
    chain_tooth_frequencies_hz: dict[str, float]
    eigenfrequencies_hz: list[float]
    node_rpm: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _drafts(surface: dict[str, float]) -> dict[str, float]:
    """Zone drafts as ratios of surface speeds; the total is their product."""
    out: dict[str, float] = {}
    if {"front", "back"} <= surface.keys():
        out["total"] = surface["front"] / surface["back"]
    if {"third", "back"} <= surface.keys():
        out["break"] = surface["third"] / surface["back"]
    if {"second", "third"} <= surface.keys():
        out["middle"] = surface["second"] / surface["third"]
    if {"front", "second"} <= surface.keys():
        out["main"] = surface["front"] / surface["second"]
    return out


def kinematics(train: DriveTrain, motor_rpm: float | None = None) -> Kinematics:
    """Nominal speeds at ``motor_rpm`` (default: the motor's rated speed)."""
    if motor_rpm is None:
        if train.spec.motor is None:
            raise ConfigError(
                "the train has no motor, so there is no rated speed to start from",
                source=train.source,
                where="--motor-rpm",
                fix="give the root node's speed (--motor-rpm)",
            )
        motor_rpm = train.spec.motor.rated_rpm
    node_rpm = train.speed_ratios * motor_rpm
    rollers: dict[str, RollerKinematics] = {}
    for r in train.spec.roller:
        rpm = float(node_rpm[train.roller_nodes[r.name]])
        v = rpm * math.pi * r.diameter_mm * 1e-3
        rollers[r.name] = RollerKinematics(rpm, r.diameter_mm, v)
    surface = {k: v.surface_speed_m_min for k, v in rollers.items()}
    idx = train.node_index
    mesh = {g.name: g.driver_teeth * node_rpm[idx(g.driver)] / 60 for g in train.spec.gear}
    chain = {c.name: c.driver_teeth * node_rpm[idx(c.driver)] / 60 for c in train.spec.chain}
    return Kinematics(
        motor_rpm=float(motor_rpm),
        rollers=rollers,
        delivery_speed_m_min=surface.get("front", float("nan")),
        drafts=_drafts(surface),
        mesh_frequencies_hz={k: float(v) for k, v in mesh.items()},
        chain_tooth_frequencies_hz={k: float(v) for k, v in chain.items()},
        eigenfrequencies_hz=eigenfrequencies_hz(train),
        node_rpm={n: float(v) for n, v in zip(train.node_names, node_rpm, strict=True)},
    )


def coupling_stiffness(train: DriveTrain) -> list[tuple[str, str, np.ndarray, float]]:
    """Each coupling's kind, name, lever vector ``v`` (m, or 1 for a shaft; ``v . theta`` is
    its deflection) and mean linear stiffness ``k`` (N/m, or N m/rad for a shaft)."""
    n = len(train.node_names)
    rows = []
    idx = train.node_index
    for kind, c in train.spec.couplings():
        if isinstance(c, TorsionalCoupling):
            a, b, ra, rb, k = idx(c.a), idx(c.b), 1.0, 1.0, c.stiffness_nm_per_rad
        elif isinstance(c, Belt):
            a, b = idx(c.driver), idx(c.driven)
            ra, rb, k = (
                c.driver_diameter_mm * 5e-4,
                c.driven_diameter_mm * 5e-4,
                c.span_stiffness_n_per_m,
            )
        elif isinstance(c, ChainDrive):
            a, b = idx(c.driver), idx(c.driven)
            # mean feed radius p z / 2 pi; both spans taut under pretension act in parallel
            ra = chain_mean_radius_m(c.pitch_mm, c.driver_teeth)
            rb = chain_mean_radius_m(c.pitch_mm, c.driven_teeth)
            k = 2 * c.span_stiffness_n_per_m
        else:
            a, b = idx(c.driver), idx(c.driven)
            (ra, rb), k = gear_base_radii_m(c), c.mesh_stiffness_n_per_m
        v = np.zeros(n)
        v[a], v[b] = ra, -rb
        rows.append((kind, c.name, v, k))
    return rows


def stiffness_matrix(train: DriveTrain) -> np.ndarray:
    """Torsional stiffness matrix (N m/rad) of the linearised train at mean stiffnesses."""
    n = len(train.node_names)
    k_mat = np.zeros((n, n))
    for _, _, v, k in coupling_stiffness(train):
        k_mat += k * np.outer(v, v)
    return k_mat


def eigenfrequencies_hz(train: DriveTrain) -> list[float]:
    """Undamped torsional eigenfrequencies (Hz) of the linearised train, rigid mode dropped."""
    lam = eigh(stiffness_matrix(train), np.diag(train.inertias), eigvals_only=True)
    lam = lam[lam > 1e-6 * lam.max()]
    return [float(f) for f in np.sqrt(lam) / (2 * math.pi)]


@dataclass(frozen=True)
class OperatingPoint:
    """Steady running state from torque balance (no integration)."""

    motor_rpm: float
    slip: float  # relative to the synchronous speed
    motor_torque_nm: float
    node_speed_rad_s: np.ndarray
    roller_rpm: dict[str, float]
    belt_creep: dict[str, float]
    transmitted: dict[str, float]  # per coupling: torque (N m) into its child node
    load_power_w: float  # roller friction loads
    bearing_power_w: float
    creep_power_w: float


def _signal_at(s: Signal | None, t: float, default: float) -> float:
    return default if s is None else float(s.at(t))


def _node_drag(train: DriveTrain, w: np.ndarray, t: float) -> tuple[np.ndarray, float, float]:
    """Net load torque per node at speeds ``w``, and the load and bearing powers (W)."""
    tab = train.tables()
    torque = np.zeros(len(w))
    powers = [0.0, 0.0]
    for (node,), (coul, eps, visc, kind) in zip(tab.drag_i, tab.drag_f, strict=True):
        t_d = coul * math.tanh(w[node] / eps) + visc * w[node]
        torque[node] += t_d
        powers[int(kind)] += t_d * w[node]
    ext = train.external_torques
    for node, s in ext:
        torque[node] -= float(s.at(t))
    return torque, powers[0], powers[1]


def operating_point(train: DriveTrain, t: float = 0.0, iterations: int = 30) -> OperatingPoint:
    """Steady state with the inputs held at their values at time ``t`` (s)."""
    tab = train.tables()
    mot = train.spec.motor
    if mot is None:
        raise ConfigError(
            "a train without a motor has no torque-balance operating point",
            source=train.source,
            where="[motor]",
            fix="add a [motor] or simulate from rest",
        )
    t_k, slip_k, pole_pairs = tab.motor_f[0, 0], tab.motor_f[0, 1], tab.motor_f[0, 2]
    supply = _signal_at(train.supply_hz, t, mot.supply_hz)
    if not supply > 0.0:
        raise ConfigError(
            f"the motor's supply is {supply:g} Hz at t = {t:g} s: a stopped train has no "
            "running operating point",
            source=train.source,
            where="[motor] supply_hz",
            fix="simulate from rest (from_rest=True) or give a positive supply frequency",
        )
    w_sync = 2 * math.pi * supply / pole_pairs
    slip_k *= _signal_at(train.rotor_resistance, t, 1.0)
    root = train.node_index(mot.node)
    ratios = train.speed_ratios
    creep = {e.coupling.name: 0.0 for e in train.edges if e.kind == "belt"}
    w_m = w_sync
    for _ in range(iterations):
        factor = np.ones(len(ratios))
        for e in train.edges:
            loss = 1.0 - creep[e.coupling.name] if e.kind == "belt" else 1.0
            factor[e.child] = factor[e.parent] * loss
        w = ratios * factor * w_m
        drag, p_load, p_bear = _node_drag(train, w, t)
        p_sub = drag * w
        transmitted: dict[str, float] = {}
        p_creep = 0.0
        for e in reversed(train.edges):
            transmitted[e.coupling.name] = p_sub[e.child] / w[e.child]
            through = p_sub[e.child]
            belt = e.coupling
            if isinstance(belt, Belt):
                pull = through / (belt.driven_diameter_mm * 5e-4 * w[e.child])
                creep[belt.name] = pull / belt.axial_rigidity_n
                loss = pull * belt.driver_diameter_mm * 5e-4 * w[e.parent] * creep[belt.name]
                p_creep += loss
                through += loss
            p_sub[e.parent] += through
        t_m = p_sub[root] / w_m
        if t_m >= t_k:
            raise ConfigError(
                f"the load torque {t_m:.1f} N m reaches the motor's breakdown torque {t_k:.1f} N m",
                source=train.source,
                where="[motor]",
                fix="use a stronger motor or lighter loads",
            )
        x = (t_k - math.sqrt(t_k * t_k - t_m * t_m)) / t_m if t_m > 0 else 0.0
        w_m = w_sync - x * slip_k
    rollers = {name: float(w[node] * 30 / math.pi) for name, node in train.roller_nodes.items()}
    return OperatingPoint(
        motor_rpm=w_m * RPM,
        slip=1.0 - w_m / w_sync,
        motor_torque_nm=t_m,
        node_speed_rad_s=w,
        roller_rpm=rollers,
        belt_creep=dict(creep),
        transmitted=transmitted,
        load_power_w=p_load,
        bearing_power_w=p_bear,
        creep_power_w=p_creep,
    )


__all__ = [
    "Kinematics",
    "OperatingPoint",
    "RollerKinematics",
    "chain_pitch_radius_m",
    "coupling_stiffness",
    "eigenfrequencies_hz",
    "kinematics",
    "operating_point",
    "stiffness_matrix",
]
