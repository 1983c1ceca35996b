"""The true surface travel of the bottom rollers at a fine time resolution.

The sliver is drafted by the rollers' surfaces, not their angles: a bottom roller with radius
run-out (eccentricity ``e``) turns with the angle ``theta`` the drive train gives it, and its
surface moves at ``omega (r + e sin(theta + phase))``, once per revolution faster and slower.
The drive train model does not need this (the roller's radius carries no torque path), so it
is applied afterwards, to the simulated angles:

* :func:`simulate_surface` runs the plant's simulation at ``surface_rate_hz`` (an integer
  multiple ``m`` of the recording's rate) and returns the recording's result at ``rate_hz``
  from every ``m``-th angle (bit-identical to a run at ``rate_hz``, see
  :func:`drafttwin.mechanics.simulation.decimation_factor`) with the rollers' fine angles;
* :func:`roller_surface` turns the fine angles into cumulative surface lengths.

Run-out (:class:`RunOut`): every roller has the healthy eccentricity
``Eccentricity.roller_eccentricity_um`` at the random phase of its healthy load modulation
(:func:`drafttwin.plant.effects.disturbances`); a roller ``eccentricity`` fault adds
``severity / roller_load_modulation x roller_eccentricity_um`` (the healthy roller's ratio of
radius run-out to load modulation) at the fault's own phase, growing with its profile.

Approximation: the load modulation's phase is open loop, ``2 pi cumsum(rev_hz) dt + phase``
at the operating point's speed from the start of the simulation (settling included), while
the radius uses the simulated angle, ``theta + phase`` (``theta`` counted from the same
start, the static deflection angle there being small). The long radius and the highest load
coincide while the roller runs at its operating-point speed; they drift apart by the
integral of the speed's deviation from it (slip, supply jitter, start-up), and the open-loop
phase leads by one force-grid step of rotation (1 ms: 0.19 rad for the front roller).
Measured on the default steady run (seed 3): the front roller's load phase leads its radius
phase by 0.33 rad at t = 0 (the grid step plus the settling second) and 1.4 rad at 10 s
(the roller turns 0.06 % slower than the operating point, which leaves out the drafting
force: 0.11 rad/s), the other rollers by a quarter of that; over minutes the two phases
are unrelated. The radius is the roller's own geometry, so it is the angle-locked term.
"""

from __future__ import annotations

import cmath
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from drafttwin._constants import ROLLERS
from drafttwin.errors import ConfigError
from drafttwin.mechanics import DriveTrain
from drafttwin.mechanics.assembly import Tables
from drafttwin.mechanics.simulation import (
    SimulationPiece,
    SimulationResult,
    decimation_factor,
    interval_means,
    simulate_chunks,
)
from drafttwin.plant.config import PlantConfig
from drafttwin.plant.faults import FaultSpec

CHUNK_S = 60.0
"""Machine time per piece of the fine simulation, s: memory holds one piece at the fine rate
and the whole record only at the recording's rate (plus the rollers' fine angles)."""


@dataclass(frozen=True)
class RollerSurface:
    """True surface length of each bottom roller, m, at a fine time grid.

    Attributes:
        time_s: ``(n + 1,)`` uniform, from the start of recording (t = 0) to its end, s.
        length_m: ``(n + 1, 4)`` cumulative surface length of front, second, third, back, m,
            0 at t = 0.
        eccentricity_um: each roller's radius eccentricity at the end of the record, um:
            the healthy run-out and a fault's added one as phasors (the amplitude of the
            once-per-revolution radius term there).
        rollers: the columns of ``length_m``.
    """

    time_s: np.ndarray
    length_m: np.ndarray
    eccentricity_um: dict[str, float]
    rollers: tuple[str, ...] = ROLLERS


@dataclass(frozen=True)
class RunOut:
    """One once-per-revolution radius term of a roller: ``e(t) sin(theta + phase_rad)``.

    Attributes:
        roller: roller name.
        eccentricity_um: full eccentricity, um.
        phase_rad: phase, rad (the same as the load modulation's).
        fault: the fault whose profile scales it in time (None: healthy, constant).
    """

    roller: str
    eccentricity_um: float
    phase_rad: float
    fault: FaultSpec | None = None

    def eccentricity_m(self, t: np.ndarray) -> float | np.ndarray:
        """Eccentricity at times ``t`` (s), m: a constant for the healthy run-out."""
        e = self.eccentricity_um * 1e-6
        return e if self.fault is None else e * self.fault.profile(t)

    def record(self) -> dict[str, Any]:
        return {"roller": self.roller, "eccentricity_um": self.eccentricity_um,
                "phase_rad": self.phase_rad,
                "source": "healthy" if self.fault is None else self.fault.label()}  # fmt: skip


def surface_factor(surface_rate_hz: float, rate_hz: float) -> int:
    """``m`` with ``surface_rate_hz == m * rate_hz`` exactly, else :class:`ConfigError`."""
    ok = math.isfinite(surface_rate_hz) and surface_rate_hz >= rate_hz > 0
    m = int(round(surface_rate_hz / rate_hz)) if ok else 0
    if not ok or m * rate_hz != surface_rate_hz:
        raise ConfigError(
            f"surface rate {surface_rate_hz:g} Hz is not a whole multiple of the recording's "
            f"rate {rate_hz:g} Hz",
            where="surface_rate_hz",
            fix=f"give a multiple of {rate_hz:g} Hz, e.g. {20 * rate_hz:g}",
        )
    return m


def run_outs(cfg: PlantConfig, healthy_phase: dict[str, float], faults: Sequence[FaultSpec],
             fault_phase: dict[str, float]) -> list[RunOut]:  # fmt: skip
    """Every radius run-out term: the healthy one of each roller, then each roller
    ``eccentricity`` fault's (``fault_phase``: roller -> its phase, rad)."""
    ecc = cfg.eccentricity
    out = [RunOut(r, ecc.roller_eccentricity_um, healthy_phase[r]) for r in ROLLERS]
    for f in faults:
        if f.kind != "eccentricity":
            continue
        if ecc.roller_load_modulation == 0.0:
            raise ConfigError(
                "a roller eccentricity fault's radius run-out is scaled by the healthy "
                "roller's (roller_eccentricity_um per roller_load_modulation), and "
                "roller_load_modulation is 0",
                where="eccentricity.roller_load_modulation",
                fix="give roller_load_modulation > 0 to record roller surfaces with this fault",
            )
        e_um = f.severity / ecc.roller_load_modulation * ecc.roller_eccentricity_um
        out.append(RunOut(f.element, e_um, fault_phase[f.element], f))
    return out


def simulate_surface(train: DriveTrain, duration_s: float, *, rate_hz: float,
                     surface_rate_hz: float, settle_s: float, from_rest: bool,
                     progress: Callable[[float], None] | None,
                     tables_at: Callable[[float], Tables] | None,
                     ) -> tuple[SimulationResult, np.ndarray]:  # fmt: skip
    """Simulate at ``surface_rate_hz``: the result at ``rate_hz`` (bit-identical to
    :func:`~drafttwin.mechanics.simulate` at ``rate_hz``; ``angle_rad`` at its rows) and the
    angles of the roller nodes (front, second, third, back), rad, ``(m n + 1, 4)``."""
    kw: dict[str, Any] = {"settle_s": settle_s, "from_rest": from_rest, "tables_at": tables_at}
    coarse = simulate_chunks(train, duration_s, chunk_s=math.inf, output_rate_hz=rate_hz, **kw)
    fine = simulate_chunks(train, coarse.n_rows / rate_hz, chunk_s=CHUNK_S,
                           output_rate_hz=surface_rate_hz, progress=progress, angles=True,
                           **kw)  # fmt: skip
    m = decimation_factor(coarse, fine)
    if m is None:
        raise ConfigError(
            f"at {surface_rate_hz:g} Hz the simulator would step differently than at "
            f"{rate_hz:g} Hz (RK4 step {fine.dt_s:.6g} s vs {coarse.dt_s:.6g} s, or kernel "
            "calls cut elsewhere), so the recording would change",
            where="surface_rate_hz",
            fix="give a surface rate whose output interval is a whole number of the "
            "recording's RK4 steps",
        )
    cols = [fine.rollers[r] for r in ROLLERS]
    parts, start = [], []
    for piece in fine:
        assert piece.angle_rad is not None
        if piece.start_row == 0:
            start = [piece.angle_rad[:1], piece.angle_rad[:1, cols]]
        parts.append(_decimated(piece, m, cols))
    angles = np.vstack([start[0], *(p[0] for p in parts)])
    result = SimulationResult(
        time_s=np.concatenate([p[1] for p in parts]),
        node_rpm=interval_means(angles, rate_hz),
        point_rpm=np.vstack([p[2] for p in parts]),
        energy_j=np.vstack([p[3] for p in parts]),
        node_names=fine.node_names, rollers=fine.rollers, motor_node=fine.motor_node,
        dt_s=fine.dt_s, wall_s=fine.wall_s, compile_s=fine.compile_s, angle_rad=angles,
    )  # fmt: skip
    return result, np.vstack([start[1], *(p[4] for p in parts)])


def _decimated(piece: SimulationPiece, m: int, cols: list[int]) -> tuple[np.ndarray, ...]:
    """A fine piece's rows at every ``m``-th interval end of the record (angles, time, point
    speeds, energy) and its roller angles at every interval end."""
    assert piece.angle_rad is not None
    ends = np.arange(piece.start_row + 1, piece.start_row + len(piece.time_s) + 1)
    keep = ends % m == 0
    a = piece.angle_rad[1:]
    return a[keep], piece.time_s[keep], piece.point_rpm[keep], piece.energy_j[keep], a[:, cols]


def roller_surface(angles: np.ndarray, surface_rate_hz: float, radius_m: dict[str, float],
                   runouts: Sequence[RunOut],
                   flutes: Sequence[FaultSpec] = ()) -> RollerSurface:  # fmt: skip
    """Cumulative surface lengths from the rollers' angles (rad, ``(n + 1, 4)``, row 0 at the
    start of recording, rows ``1 / surface_rate_hz`` apart) and true radii (m).

    ``length = r (theta - theta_0) + sum over run-outs of e (cos(theta_0 + phase) -
    cos(theta + phase))``, the integral of ``omega (r + e sin(theta + phase))``: exact for a
    constant ``e`` (the healthy run-out). A fault's growing ``e(t)`` is taken at the middle
    of each fine interval and the increments are summed (no jump at an abrupt onset; the
    neglected term is ``e'(t)`` times the cosine's change, zero for a constant ``e``).
    """
    n = angles.shape[0] - 1
    t = np.arange(n + 1) / surface_rate_hz
    t_mid = (np.arange(n) + 0.5) / surface_rate_hz
    length = np.empty_like(angles)
    end: dict[str, complex] = {}
    for k, r in enumerate(ROLLERS):
        th = angles[:, k]
        length[:, k] = radius_m[r] * (th - th[0])
        for ro in (ro for ro in runouts if ro.roller == r):
            e = ro.eccentricity_m(t_mid)
            length[:, k] += _runout_length(th, e, ro.phase_rad)
            e_end = ro.eccentricity_um if ro.fault is None else ro.eccentricity_m(t[-1]) * 1e6
            end[r] = end.get(r, 0j) + cmath.rect(float(e_end), ro.phase_rad)
        for f in (f for f in flutes if f.element == r):
            arc = np.diff(_flute_arc(th - th[0]))
            lost = radius_m[r] * f.severity * f.profile(t_mid) * arc
            length[1:, k] -= np.cumsum(lost)
    return RollerSurface(t, length, {r: abs(end.get(r, 0j)) for r in ROLLERS})


FLUTE_ARC = 1.0 / 20.0
"""A damaged flute's share of the circumference (assumption: a few flutes of a 45-mm roller's
about 40)."""


def _flute_arc(theta: np.ndarray) -> np.ndarray:
    """Angle (rad) turned within the damaged arc ``[0, 2 pi FLUTE_ARC)`` of each revolution,
    cumulative from ``theta = 0``."""
    turns = np.floor(theta / (2 * math.pi))
    within = theta - 2 * math.pi * turns
    return turns * 2 * math.pi * FLUTE_ARC + np.minimum(within, 2 * math.pi * FLUTE_ARC)


def _runout_length(theta: np.ndarray, e: float | np.ndarray, phase: float) -> np.ndarray:
    """Surface length of ``e sin(theta + phase)`` on the radius, m, 0 at row 0."""
    c = np.cos(theta + phase)
    if np.ndim(e) == 0:
        length: np.ndarray = e * (c[0] - c)
        return length
    return np.concatenate([[0.0], np.cumsum(e * (c[:-1] - c[1:]))])


def surface_info(surface_rate_hz: float, radius_m: dict[str, float],
                 runouts: Sequence[RunOut], surface: RollerSurface) -> dict[str, Any]:  # fmt: skip
    """The sidecar's record of the surfaces (``info["surface"]``)."""
    return {
        "rate_hz": surface_rate_hz,
        "rollers": list(surface.rollers),
        "radius_m": dict(radius_m),
        "eccentricity_um": dict(surface.eccentricity_um),
        "run_outs": [ro.record() for ro in runouts],
        "radius": "r + e sin(theta + phase_rad), theta the roller's simulated angle",
    }
