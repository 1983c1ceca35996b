"""The wavelength table of a drive train: every rotating element's line on the sliver.

An element turning at ``f`` Hz that modulates the rollers leaves its mark on the delivered
sliver at ``lambda = v_delivery / f`` (and ``lambda / h`` for its harmonics). The table lists
every element of the train at its running point: the motor, each node (shaft), each gear of
every mesh and the mesh itself, belt pulleys and the belt pass, chain sprockets, the chain
pass and its tooth (polygon) frequency, and each bottom roller's once-per-revolution line (an
eccentric roller's radius). Each element also names the rollers it moves: those driven
through it (its coupling's child side) or, for a roller's radius, that roller alone; the
drafting transfer (:mod:`drafttwin.sliver.transfer`) then tells how strongly it can show.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import pandas as pd

from drafttwin.errors import ConfigError
from drafttwin.mechanics import DriveTrain, operating_point
from drafttwin.mechanics.components import Belt, ChainDrive, GearMesh

FA320A_BELT_LENGTH_MM = 1200.0
"""Main belt length (assumption: 150/125 mm pulleys at about 450 mm centres)."""
FA320A_CHAIN_LINKS = 62
"""Pitches in the rear chain (the plant's assumption, research/faults.md 2.5)."""


@dataclass(frozen=True)
class Element:
    """One rotating element and its line on the sliver.

    Attributes:
        name: e.g. ``gear B (A-B)``, ``roller front``, ``belt pass main_belt``.
        kind: motor | shaft | gear | mesh | pulley | belt | sprocket | chain | roller |
            rattle (half a mesh's or a chain's tooth frequency: a lightly loaded mesh below it
            that loses contact once every two teeth, the period doubling of a gear pair with
            backlash; its odd orders only, the even ones are the tooth frequency's own).
        node: the drive-train node it turns with ('' for a belt or chain pass).
        frequency_hz: its rotation (or pass, or mesh) frequency at the running point.
        wavelength_m: ``v_delivery / frequency_hz`` on the delivered sliver.
        rollers: the bottom rollers whose surface speed it modulates.
    """

    name: str
    kind: str
    node: str
    frequency_hz: float
    wavelength_m: float
    rollers: tuple[str, ...]

    def orders(self, count: int) -> range:
        """The harmonic orders up to ``count`` that are this element's own: all, or the odd
        ones of a rattle line (its even ones are the tooth frequency's)."""
        return range(1, count + 1, 2 if self.kind == "rattle" else 1)

    def harmonics_m(self, count: int) -> list[float]:
        return [self.wavelength_m / h for h in range(1, count + 1)]


@dataclass(frozen=True)
class WavelengthTable:
    """Every element of a train with its wavelength at one running point."""

    train: str
    delivery_m_min: float
    motor_rpm: float
    elements: tuple[Element, ...]
    harmonics: int = 3

    def to_frame(self) -> pd.DataFrame:
        rows = []
        for e in self.elements:
            row = {k: v for k, v in asdict(e).items() if k != "rollers"}
            row["rollers"] = ",".join(e.rollers)
            for h in range(2, self.harmonics + 1):
                row[f"h{h}_wavelength_m"] = e.wavelength_m / h
            rows.append(row)
        return pd.DataFrame(rows)

    def to_dict(self) -> dict[str, Any]:
        return {"train": self.train, "delivery_m_min": self.delivery_m_min,
                "motor_rpm": self.motor_rpm, "harmonics": self.harmonics,
                "elements": [asdict(e) | {"harmonics_m": e.harmonics_m(self.harmonics)}
                             for e in self.elements]}  # fmt: skip

    def near(self, wavelength_m: float, rel: float, harmonics: int | None = None
             ) -> list[tuple[Element, int]]:  # fmt: skip
        """Elements (and harmonic order) within relative distance ``rel`` of a wavelength."""
        out = []
        for e in self.elements:
            for h in e.orders(harmonics or self.harmonics):
                if abs(math.log(e.wavelength_m / h / wavelength_m)) <= math.log1p(rel):
                    out.append((e, h))
        return out


def wavelength_table(train: DriveTrain, *, motor_rpm: float | None = None, harmonics: int = 3,
                     belt_length_mm: float | None = None,
                     chain_links: int | None = None) -> WavelengthTable:  # fmt: skip
    """The table at the running point (torque balance: slip and creep included) or, with
    ``motor_rpm``, at that motor speed without slip or creep. ``belt_length_mm`` and
    ``chain_links`` give the belt and chain passes (FA320A: assumed values by default)."""
    if "front" not in train.roller_nodes:
        raise ConfigError("the train has no front roller, so there is no delivered sliver",
                          source=train.source, where="[[roller]]",
                          fix="name the delivering roller 'front'")  # fmt: skip
    rps = _node_rps(train, motor_rpm)
    front = next(r for r in train.spec.roller if r.name == "front")
    v = rps[train.roller_nodes["front"]] * math.pi * front.diameter_mm * 1e-3  # m/s
    is_fa320a = train.spec.train.name.startswith("fa320a")
    belt_mm = belt_length_mm or (FA320A_BELT_LENGTH_MM if is_fa320a else None)
    links = chain_links or (FA320A_CHAIN_LINKS if is_fa320a else None)
    below = _rollers_below(train)
    elements = [*_node_elements(train, rps, v, below), *_roller_elements(train, rps, v),
                *_coupling_elements(train, rps, v, below, belt_mm, links)]  # fmt: skip
    motor = train.spec.motor
    root_rpm = float(rps[train.node_index(train.spec.root_node)] * 60)
    return WavelengthTable(
        train.spec.train.name,
        v * 60,
        root_rpm if motor else root_rpm,
        tuple(sorted(elements, key=lambda e: -e.wavelength_m)),
        harmonics,
    )


def _node_rps(train: DriveTrain, motor_rpm: float | None) -> np.ndarray:
    if motor_rpm is None and train.spec.motor is not None:
        return operating_point(train).node_speed_rad_s / (2 * math.pi)
    if motor_rpm is None:
        raise ConfigError("the train has no motor: give its root speed", where="--motor-rpm")
    return train.speed_ratios * motor_rpm / 60.0


def _rollers_below(train: DriveTrain) -> dict[int, tuple[str, ...]]:
    """Rollers in the subtree of each node (the node itself included)."""
    children: dict[int, list[int]] = {}
    for e in train.edges:
        children.setdefault(e.parent, []).append(e.child)
    roller_at = {node: name for name, node in train.roller_nodes.items()}
    out: dict[int, tuple[str, ...]] = {}

    def walk(n: int) -> tuple[str, ...]:
        if n not in out:
            found = [roller_at[n]] if n in roller_at else []
            for c in children.get(n, []):
                found.extend(walk(c))
            out[n] = tuple(found)
        return out[n]

    for n in range(len(train.node_names)):
        walk(n)
    return out


def _element(name: str, kind: str, node: str, f: float, v: float,
             rollers: tuple[str, ...]) -> Element:  # fmt: skip
    order = ("front", "second", "third", "back")
    ordered = tuple(r for r in order if r in rollers) + tuple(r for r in rollers if r not in order)
    return Element(name, kind, node, float(f), float(v / f), ordered)


def _node_elements(train: DriveTrain, rps: np.ndarray, v: float,
                   below: dict[int, tuple[str, ...]]) -> list[Element]:  # fmt: skip
    motor_node = train.spec.motor.node if train.spec.motor else None
    roller_nodes = set(train.roller_nodes.values())
    out = []
    for i, name in enumerate(train.node_names):
        if i in roller_nodes:
            continue  # a roller's own line is its radius (below)
        kind = "motor" if name == motor_node else "shaft"
        out.append(_element(f"{kind} {name}", kind, name, rps[i], v, below[i]))
    return out


def _roller_elements(train: DriveTrain, rps: np.ndarray, v: float) -> list[Element]:
    return [_element(f"roller {r.name}", "roller", r.node, rps[train.node_index(r.node)], v,
                     (r.name,)) for r in train.spec.roller]  # fmt: skip


def _gear_names(mesh: GearMesh) -> tuple[str, str]:
    parts = mesh.name.split("-")
    if len(parts) == 2 and all(parts):
        return f"gear {parts[0]} ({mesh.name})", f"gear {parts[1]} ({mesh.name})"
    return f"driver gear ({mesh.name})", f"driven gear ({mesh.name})"


def _coupling_elements(train: DriveTrain, rps: np.ndarray, v: float,
                       below: dict[int, tuple[str, ...]], belt_mm: float | None,
                       links: int | None) -> list[Element]:  # fmt: skip
    out: list[Element] = []
    names = train.node_names
    for e in train.edges:
        c, p, child = e.coupling, e.parent, e.child
        moved = below[child]
        forward = names[p] == getattr(c, "driver", None)
        drv, dvn = (p, child) if forward else (child, p)
        if isinstance(c, GearMesh):
            g_drv, g_dvn = _gear_names(c)
            out += [_element(g_drv, "gear", names[drv], rps[drv], v, moved),
                    _element(g_dvn, "gear", names[dvn], rps[dvn], v, moved),
                    _element(f"mesh {c.name}", "mesh", "", rps[drv] * c.driver_teeth, v, moved),
                    _rattle(f"of {c.name}", rps[drv] * c.driver_teeth, v, moved)]  # fmt: skip
        elif isinstance(c, Belt):
            out += [_element(f"driver pulley ({c.name})", "pulley", names[drv], rps[drv], v, moved),
                    _element(f"driven pulley ({c.name})", "pulley", names[dvn], rps[dvn], v,
                             moved)]  # fmt: skip
            if belt_mm:
                belt_speed = rps[drv] * math.pi * c.driver_diameter_mm
                out.append(_element(f"belt pass {c.name}", "belt", "", belt_speed / belt_mm, v,
                                    moved))  # fmt: skip
        elif isinstance(c, ChainDrive):
            out += [_element(f"driver sprocket ({c.name})", "sprocket", names[drv], rps[drv], v,
                             moved),
                    _element(f"driven sprocket ({c.name})", "sprocket", names[dvn], rps[dvn], v,
                             moved),
                    _element(f"chain teeth {c.name}", "chain", "", rps[drv] * c.driver_teeth, v,
                             moved),
                    _rattle(f"below {c.name}", rps[drv] * c.driver_teeth, v, moved)]  # fmt: skip
            if links:
                out.append(_element(f"chain pass {c.name}", "chain", "",
                                    rps[drv] * c.driver_teeth / links, v, moved))  # fmt: skip
    return out


def _rattle(where: str, tooth_hz: float, v: float, moved: tuple[str, ...]) -> Element:
    """Half a tooth frequency: a mesh (that one, or one below a chain) rattling in its
    backlash with period 2."""
    return _element(f"rattle {where}", "rattle", "", tooth_hz / 2, v, moved)
