"""The fault catalogue and the physics of a fault on a drive train.

What can fail on a train (:func:`catalogue`), each kind's severity, its unit and range
(:data:`KINDS`), and what a fault does to the train's parameters where both the plant (which
injects it) and the diagnosis (which predicts its signature) need the same answer: a worn
mesh's stiffness and backlash (:func:`worn_gear`), an elongated chain's slack
(:func:`chain_slack_m`). The plant's time-varying injection is in
:mod:`drafttwin.plant.faults`; docs/faults.md has the table of kinds and assumptions.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from drafttwin._constants import ROLLERS
from drafttwin.mechanics.assembly import DriveTrain

CHAIN_LINKS = 62
"""Pitches in the chain loop (assumption: a 25T + 50T drive needs >= 37.5 pitches for the wraps
alone; research/faults.md 2.5)."""
SENSOR_CHANNELS = (*ROLLERS, "motor")


@dataclass(frozen=True)
class FaultKind:
    """One kind of fault: what its severity means and the range it may take."""

    name: str
    family: str  # gear | belt | chain | bearing | roller | motor | sensor
    parameter: str  # what the severity is, with its unit
    low: float  # severity must be > low (or >= -high for signed kinds)
    high: float
    levels: tuple[float, float, float]  # light, moderate, severe (benchmarks, generate-faults)
    signed: bool = False
    ramp_allowed: bool = True


KINDS: dict[str, FaultKind] = {k.name: k for k in (
    FaultKind("crack", "gear", "mesh stiffness lost while the cracked tooth meshes (fraction)",
              0.0, 0.95, (0.2, 0.5, 0.8)),
    FaultKind("wear", "gear", "wear depth on the working flanks (um)", 0.0, 500.0,
              (20.0, 60.0, 150.0)),
    FaultKind("runout", "gear", "added eccentricity of the driven gear (um)", 0.0, 500.0,
              (10.0, 30.0, 80.0)),
    FaultKind("belt_wear", "belt", "loss of belt axial rigidity (fraction)", 0.0, 0.9,
              (0.2, 0.5, 0.8)),
    FaultKind("elongation", "chain", "chain elongation (% of its length)", 0.0, 5.0,
              (0.5, 1.5, 3.0)),
    FaultKind("bearing_friction", "bearing", "relative rise of bearing drag (1 = doubled)",
              0.0, 100.0, (2.0, 5.0, 10.0)),
    FaultKind("load_loss", "roller", "top-roller load lost (fraction)", 0.0, 1.0,
              (0.1, 0.3, 0.6)),
    FaultKind("eccentricity", "roller", "added once-per-revolution load modulation (fraction "
              "of the roller's friction load)", 0.0, 1.0, (0.05, 0.15, 0.3)),
    FaultKind("flute", "roller", "surface speed lost over a damaged flute, an arc of 1/20 of "
              "the circumference (fraction)", 0.0, 0.5, (0.02, 0.05, 0.15)),
    FaultKind("rotor_resistance", "motor", "relative rise of rotor resistance", 0.0, 2.0,
              (0.05, 0.15, 0.3)),
    FaultKind("torque_loss", "motor", "breakdown torque lost (fraction)", 0.0, 0.6,
              (0.05, 0.15, 0.3)),
    FaultKind("gain", "sensor", "relative gain error of the channel", 0.0, 0.5,
              (0.001, 0.005, 0.02), signed=True),
    FaultKind("stuck", "sensor", "time the channel repeats one value (s)", 0.0, 1e6,
              (1.0, 5.0, 30.0), ramp_allowed=False),
    FaultKind("dropout", "sensor", "fraction of the channel's samples lost", 0.0, 1.0,
              (0.05, 0.3, 1.0)),
)}  # fmt: skip
MACHINE_FAMILIES = ("gear", "belt", "chain", "bearing", "roller", "motor")
SURFACE_ONLY = ("flute",)
"""Kinds that act on a roller's surface only: no speed an encoder counts changes, so the
encoder fault benchmark leaves them out and its sliver variant has them."""


def catalogue(train: DriveTrain) -> dict[str, tuple[str, ...]]:
    """Every element of ``train`` that can fail, with its fault kinds."""
    spec = train.spec
    out: dict[str, list[str]] = {}
    fam_kinds = {f: [k.name for k in KINDS.values() if k.family == f]
                 for f in (*MACHINE_FAMILIES, "sensor")}  # fmt: skip
    for g in spec.gear:
        out.setdefault(g.name, []).extend(fam_kinds["gear"])
    for b in spec.belt:
        out.setdefault(b.name, []).extend(fam_kinds["belt"])
    for c in spec.chain:
        out.setdefault(c.name, []).extend(fam_kinds["chain"])
    for node in sorted({b.node for b in spec.bearing}):
        out.setdefault(node, []).extend(fam_kinds["bearing"])
    for r in spec.roller:
        out.setdefault(r.name, []).extend(fam_kinds["roller"])
    if spec.motor is not None:
        out.setdefault("motor", []).extend(fam_kinds["motor"])
    for ch in SENSOR_CHANNELS:
        out.setdefault(ch, []).extend(fam_kinds["sensor"])
    return {e: tuple(k) for e, k in out.items()}


def worn_stiffness_factor(depth_um: float, module_mm: float) -> float:
    """A worn mesh's stiffness over its healthy one: thinner flanks, down to half
    (assumption: the loss grows in proportion to the wear depth, Chen et al. 2021, 10 % at
    20 um on module 2)."""
    return 1.0 - min(0.5, depth_um / (100.0 * module_mm))


def worn_gear(gear: dict[str, Any], depth_um: float) -> dict[str, Any]:
    """A gear's declaration (``DriveTrain.to_dict()["gear"]`` entry) with both working
    flanks worn by ``depth_um``: the total backlash grows by twice the depth, the mesh
    stiffness falls by :func:`worn_stiffness_factor`."""
    factor = worn_stiffness_factor(depth_um, gear["module_mm"])
    return dict(gear, backlash_um=gear["backlash_um"] + 2.0 * depth_um,
                mesh_stiffness_n_per_m=gear["mesh_stiffness_n_per_m"] * factor)  # fmt: skip


def chain_slack_m(elongation_pct: float, pitch_m: float) -> float:
    """Extra loop length of a chain elongated by ``elongation_pct`` % (:data:`CHAIN_LINKS`
    pitches of ``pitch_m``), m: the pretension is lost and each span goes slack by half."""
    return elongation_pct / 100.0 * CHAIN_LINKS * pitch_m


def slacken_chain(chain_f: np.ndarray, row: int, elongation_pct: float) -> np.ndarray:
    """A copy of the kernel's chain table (``Tables.chain_f``) with chain ``row`` elongated by
    ``elongation_pct`` %: its slack (:func:`chain_slack_m`) taken off the pretension at the
    span stiffness, ``T0 - k slack / 2`` (each span goes slack by half). The plant injects an
    elongation so, and diagnosis simulates it so."""
    from drafttwin.mechanics import kernel as K

    out = np.array(chain_f, dtype=np.float64, copy=True)
    extra = chain_slack_m(elongation_pct, out[row, K.CH_P])
    out[row, K.CH_T0] -= out[row, K.CH_K] * 0.5 * extra
    return out
