"""A reduced drive train: couplings stiffer than a cut-off made rigid, for a much larger step.

:func:`reduce` returns a copy of a :class:`DriveTrain` carrying a :class:`Reduction`;
:func:`~drafttwin.mechanics.simulation.simulate` (for a duration or on a measurement grid,
and so the calibration) then integrates the reduced system and expands it back onto every node.

Which couplings become rigid: the linearised train (mean stiffnesses, as in
:func:`~drafttwin.mechanics.steady_state.eigenfrequencies_hz`) is solved for its modes; while
the highest remaining eigenfrequency is above the cut-off, the coupling holding most strain
energy in that mode is made rigid and its two ends merged (Guyan-style condensation onto
rigid super-nodes). Belts are never made rigid: their creep, a speed loss proportional to the
belt pull over the axial rigidity, is a slip and not a stiffness, and the calibration
estimates it.

Merged nodes turn together: node ``i`` has angle ``ratio[i] * Theta_c + offset[i]`` and speed
``ratio[i] * Omega_c`` with ``c`` its super-node and ``ratio`` the nominal speed ratio to the
super-node's representative (the node nearest the motor). A super-node's inertia is
``sum J_i ratio_i**2``; every torque on a node (motor, friction, bearings, external, the
remaining compliant couplings) acts on its super-node times ``ratio_i``, so power is kept.
The internal forces of rigid couplings do no work and drop out. What the reduction loses:
the deflections and vibrations of the rigid couplings (mesh-stiffness variation,
transmission error, eccentricity, chain polygon effect and backlash of rigid gears and
chains), i.e. the lines above the cut-off; interval means over several mesh periods keep.

The reduced right-hand side (:func:`~drafttwin.mechanics.kernel.reduced_rhs`) is the full
model's :func:`~drafttwin.mechanics.kernel.rhs` evaluated on the expanded state with the rigid
couplings' rows removed, so motor (Kloss curve, rotor resistance, VFD schedule, torque lag and
ripple), belt creep, friction and the energy accumulators are the same code; the same RK4
loop integrates both (:func:`~drafttwin.mechanics.kernel.integrate_reduced`).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
from scipy.linalg import eigh

from drafttwin.errors import ConfigError
from drafttwin.mechanics import kernel as K
from drafttwin.mechanics.assembly import DriveTrain, Tables
from drafttwin.mechanics.reduction import Reduction
from drafttwin.mechanics.steady_state import coupling_stiffness

DEFAULT_CUTOFF_HZ = 200.0
"""Default cut-off (Hz): above the FA320A's belt mode (55 Hz), below its roller-torsion modes
(470-530 Hz), chain (930 Hz) and gear-mesh modes (1.9-5.5 kHz); everything but the belt goes
rigid."""

OMEGA_DT = 0.5
"""Default step: ``omega * dt`` at most this for the fastest remaining rate (RK4 is stable to
2.8 on the imaginary axis and 2.78 on the real one; 0.5 keeps its phase error near 1e-3)."""

MAX_STEP_S = 2e-3
"""Upper bound (s) on the default step, whatever the rates (set-point ramps, output grid)."""


# ---- which couplings go rigid ------------------------------------------------------------
def _order(train: DriveTrain) -> np.ndarray:
    """Breadth-first rank of each node from the motor (representatives are the lowest)."""
    rank = np.full(len(train.node_names), len(train.node_names), dtype=np.int64)
    rank[train.node_index(train.spec.root_node)] = 0
    for k, e in enumerate(train.edges):
        rank[e.child] = k + 1
    return rank


def _clusters(n: int, merged: list[tuple[int, int]], rank: np.ndarray) -> np.ndarray:
    """Super-node of each node, numbered by their representatives' rank."""
    parent = list(range(n))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b in merged:
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[max(ra, rb, key=lambda x: rank[x])] = min(ra, rb, key=lambda x: rank[x])
    roots = sorted({find(i) for i in range(n)}, key=lambda x: rank[x])
    number = {r: c for c, r in enumerate(roots)}
    return np.array([number[find(i)] for i in range(n)], dtype=np.int64)


def _transform(cluster: np.ndarray, ratio: np.ndarray) -> np.ndarray:
    """``T`` with node angles ``theta = T Theta`` (super-node angles), shape ``(n, m)``."""
    t = np.zeros((len(cluster), int(cluster.max()) + 1))
    t[np.arange(len(cluster)), cluster] = ratio
    return t


def _representatives(train: DriveTrain, cluster: np.ndarray) -> np.ndarray:
    """The node of each super-node nearest the motor (its speed is the super-node's)."""
    rank = _order(train)
    rep = np.zeros(int(cluster.max()) + 1, dtype=np.int64)
    for c in range(len(rep)):
        members = np.flatnonzero(cluster == c)
        rep[c] = members[np.argmin(rank[members])]
    return rep


def _node_ratios(train: DriveTrain, cluster: np.ndarray) -> np.ndarray:
    """Speed of each node over its super-node representative's (nominal ratios)."""
    speed = train.speed_ratios
    ratios: np.ndarray = speed / speed[_representatives(train, cluster)[cluster]]
    return ratios


def _highest_mode(
    k_full: np.ndarray, inertias: np.ndarray, t: np.ndarray
) -> tuple[float, np.ndarray]:
    """Highest eigenfrequency (Hz) of ``T' K T, T' M T`` and its mode on the nodes."""
    if t.shape[1] < 2:
        return 0.0, np.zeros(t.shape[0])
    lam, vec = eigh(t.T @ k_full @ t, t.T @ np.diag(inertias) @ t)
    if not lam[-1] > 1e-9 * max(abs(lam[0]), 1.0):
        return 0.0, np.zeros(t.shape[0])
    return math.sqrt(lam[-1]) / (2 * math.pi), t @ vec[:, -1]


def _rigid_couplings(
    train: DriveTrain, cutoff_hz: float
) -> tuple[list[tuple[str, str]], np.ndarray, float]:
    """Greedy: make the most strained non-belt coupling of the highest mode rigid until that
    mode is at or below ``cutoff_hz``. Returns (kind, name) made rigid, clusters, highest Hz."""
    rows = coupling_stiffness(train)
    n = len(train.node_names)
    k_full = sum((k * np.outer(v, v) for _, _, v, k in rows), np.zeros((n, n)))
    rank = _order(train)
    rigid: list[int] = []
    cluster = np.arange(n, dtype=np.int64)
    while True:
        t = _transform(cluster, _node_ratios(train, cluster))
        f_hz, mode = _highest_mode(k_full, train.inertias, t)
        if f_hz <= cutoff_hz:
            break
        strain = [0.0 if kind == "belt" or j in rigid else k * float(v @ mode) ** 2
                  for j, (kind, _, v, k) in enumerate(rows)]  # fmt: skip
        j = int(np.argmax(strain))
        if strain[j] <= 1e-6 * sum(k * float(v @ mode) ** 2 for _, _, v, k in rows):
            break  # the mode lives in the belts, which stay compliant
        rigid.append(j)
        cluster = _clusters(n, [_ends(rows[i][2]) for i in rigid], rank)
    return [(rows[j][0], rows[j][1]) for j in rigid], cluster, f_hz


def _ends(v: np.ndarray) -> tuple[int, int]:
    a, b = np.flatnonzero(v)
    return int(a), int(b)


# ---- step ---------------------------------------------------------------------------------
def _default_step(train: DriveTrain, cluster: np.ndarray, ratio: np.ndarray, f_hz: float) -> float:
    """Step (s) with ``rate * dt <= OMEGA_DT`` for the highest mode, the motor's torque lag
    and Kloss slope, and the friction slopes at rest, on the super-node inertias."""
    j_super = np.bincount(cluster, weights=train.inertias * ratio**2)
    rates = [2 * math.pi * f_hz]
    tab = train.tables()
    for (node,), (coul, eps, visc, _) in zip(tab.drag_i, tab.drag_f, strict=True):
        rates.append(ratio[node] ** 2 * (coul / eps + visc) / j_super[cluster[node]])
    mot = train.spec.motor
    if mot is not None:
        node = train.node_index(mot.node)
        t_k, slip_k = tab.motor_f[0, K.MOT_TK], tab.motor_f[0, K.MOT_SK]
        rates.append(1.0 / mot.torque_lag_s)
        rates.append(2 * t_k / slip_k * ratio[node] ** 2 / j_super[cluster[node]])
    fastest = max(rates)  # 0 for a rigid train without friction or motor: any step is exact
    return min(MAX_STEP_S, OMEGA_DT / fastest) if fastest > 0 else MAX_STEP_S


# ---- public -------------------------------------------------------------------------------
def reduce(train: DriveTrain, cutoff_hz: float = DEFAULT_CUTOFF_HZ) -> DriveTrain:
    """The train with its couplings above ``cutoff_hz`` (Hz) made rigid (see the module).

    The result is a :class:`DriveTrain` (same nodes, inputs and outputs) that every simulation
    function integrates in reduced form, by default with the reduction's step. A train that is
    already reduced is reduced again from its full form. Takes about a millisecond.

    Raises:
        ConfigError: ``cutoff_hz`` is not a positive finite number.
    """
    if not (isinstance(cutoff_hz, int | float) and math.isfinite(cutoff_hz) and cutoff_hz > 0):
        raise ConfigError(
            f"the reduction cut-off must be a positive frequency in Hz, got {cutoff_hz!r}",
            source=train.source,
            where="--cutoff-hz",
            fix=f"give a frequency above 0, e.g. {DEFAULT_CUTOFF_HZ:g} (see the train's "
            "eigenfrequencies in 'drafttwin kinematics')",
        )
    rigid, cluster, f_hz = _rigid_couplings(train, float(cutoff_hz))
    ratio = _node_ratios(train, cluster)
    gone = {name for _, name in rigid}
    rows: dict[str, list[Any]] = {
        "chain": train.spec.chain, "gear": train.spec.gear, "spring": train.spec.springs()
    }  # fmt: skip
    keep = {table: np.array([c.name not in gone for c in couplings], dtype=bool)
            for table, couplings in rows.items()}  # fmt: skip
    red = Reduction(float(cutoff_hz), cluster, ratio, tuple(sorted(gone)), f_hz,
                    _default_step(train, cluster, ratio, f_hz), keep)  # fmt: skip
    return replace(train, reduction=red)


def reduced_tables(tab: Tables, red: Reduction) -> Tables:
    """The full tables without the rigid couplings' rows."""
    chain, gear, spring = red.keep["chain"], red.keep["gear"], red.keep["spring"]
    return tab._replace(chain_i=tab.chain_i[chain], chain_f=tab.chain_f[chain],
                        gear_i=tab.gear_i[gear], gear_f=tab.gear_f[gear],
                        spring_i=tab.spring_i[spring], spring_f=tab.spring_f[spring])  # fmt: skip


def reduced_start(train: DriveTrain, y_full: np.ndarray) -> tuple[np.ndarray, K.ReducedTables]:
    """Reduced state and the kernel's bundle from a full start state (rest or operating point).

    Super-node angle and speed are those of its representative; the other nodes' offsets
    keep the static deflections of the start state (preloads of the compliant couplings).
    """
    red = train.reduction
    assert red is not None
    n = len(train.node_names)
    rep = _representatives(train, red.cluster)
    y = np.concatenate([y_full[rep], y_full[n + rep], y_full[2 * n :]])
    offset = y_full[:n] - red.ratio * y[red.cluster]
    inv_jc = 1.0 / np.bincount(red.cluster, weights=train.inertias * red.ratio**2)
    # inv_j all ones: the full right-hand side returns node torques, reflected onto super-nodes
    tab = reduced_tables(train.tables(), red)._replace(inv_j=np.ones(n)).kernel()
    work = np.zeros((2, len(y_full)))
    return y, K.ReducedTables(red.cluster, red.ratio, offset, inv_jc, tab, work)


def expand_angles(y: np.ndarray, model: K.ReducedTables) -> np.ndarray:
    """Node angles (rad) of a reduced state ``y`` (``model`` from :func:`reduced_start`)."""
    angles: np.ndarray = model.ratio * y[model.cluster] + model.offset
    return angles


def describe(train: DriveTrain) -> dict[str, Any]:
    """The reduction of a reduced train as plain data (for reports and ``--json``)."""
    red = train.reduction
    if red is None:
        return {}
    groups = [[train.node_names[i] for i in np.flatnonzero(red.cluster == c)]
              for c in range(red.n_super)]  # fmt: skip
    return {"cutoff_hz": red.cutoff_hz, "super_nodes": groups, "rigid": list(red.rigid),
            "highest_mode_hz": red.highest_hz, "dt_s": red.dt_s}  # fmt: skip


__all__ = ["DEFAULT_CUTOFF_HZ", "Reduction", "describe", "reduce"]
