"""What the real machine has and the nominal mechanistic model leaves out.

* :func:`true_train`: the drive train with true parameters (seeded mismatch, backlash,
  gear eccentricity with random phases).
* :func:`ou_process`: a stationary Ornstein-Uhlenbeck process (exact discretisation), the
  building block of the colored disturbances.
* :func:`disturbances`: drafting-force torques, roller load modulation (run-out), rotor
  resistance drift (warming) and supply-frequency jitter as signals on uniform grids, after
  the machine's run-up where one is asked for.

Each random effect draws from its own stream, sequentially in time, so a shorter run with the
same seed is an exact prefix of a longer one.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.signal import lfilter

from drafttwin.mechanics import DriveTrain, Signal, operating_point
from drafttwin.mechanics.components import Roller
from drafttwin.plant.config import Eccentricity, PlantConfig

FORCE_GRID_S = 1e-3  # drafting force and roller load grid (lines up to ~30 Hz once-per-rev)
SUPPLY_GRID_S = 1e-2
THERMAL_GRID_S = 1.0


def true_train(
    nominal: DriveTrain, cfg: PlantConfig, rng: np.random.Generator
) -> tuple[DriveTrain, dict[str, float]]:
    """The plant's drive train and the relative deviations drawn for it."""
    raw = nominal.to_dict()
    # the plant draws the drafting force itself (a colored process, DraftingForce), so the
    # train's own mean drafting zones would count it twice
    raw.pop("drafting_zone", None)
    mm = cfg.mismatch
    draws: dict[str, float] = {}
    # the gears' own run-outs from a child stream, so that every other draw stays as it was
    (runout_rng,) = rng.spawn(1)

    def scale(item: dict[str, Any], key: str, half_range: float, label: str) -> None:
        u = float(rng.uniform(-half_range, half_range))
        draws[f"{label}.{key}"] = u
        item[key] *= 1.0 + u

    for r in raw["roller"]:
        scale(r, "friction_coefficient", mm.friction_coefficient, f"roller.{r['name']}")
    for b in raw["belt"]:
        scale(b, "axial_rigidity_n", mm.belt_axial_rigidity, f"belt.{b['name']}")
    for c in raw["chain"]:
        scale(c, "span_stiffness_n_per_m", mm.chain_span_stiffness, f"chain.{c['name']}")
    for g in raw["gear"]:
        scale(g, "mesh_stiffness_n_per_m", mm.mesh_stiffness, f"gear.{g['name']}")
        g["backlash_um"] = cfg.backlash_module_fraction * g["module_mm"] * 1000.0
        for side in ("driver", "driven"):
            g[f"{side}_eccentricity_um"] = gear_eccentricity_um(cfg.eccentricity, runout_rng)
            g[f"{side}_eccentricity_phase_deg"] = float(rng.uniform(0.0, 360.0))
    for s in raw["shaft"]:
        scale(s, "stiffness_nm_per_rad", mm.roller_torsion, f"shaft.{s['name']}")
    for b in raw["bearing"]:  # one draw per node: its bearings are one calibration factor
        name = f"bearing.{b['node']}"
        if name not in draws:
            draws[name] = float(rng.uniform(-mm.bearing_friction, mm.bearing_friction))
        u = draws[name]
        b["coulomb_torque_nm"] *= 1.0 + u
        b["viscous_nms"] *= 1.0 + u
    scale(raw["motor"], "breakdown_torque_ratio", mm.breakdown_torque_ratio, "motor")
    raw["train"]["name"] = f"{raw['train']['name']} (plant)"
    return DriveTrain.from_dict(raw, source="plant"), draws


# P(R <= k sigma) = 1 - exp(-k^2 / 2) = 0.9973 for a Rayleigh R: the 99.73 % field (3.44 sigma)
RAYLEIGH_FIELD_SIGMAS = math.sqrt(-2.0 * math.log(1.0 - 0.9973))


def gear_eccentricity_um(ecc: Eccentricity, rng: np.random.Generator) -> float:
    """One gear's eccentricity (um, half its radial run-out) under ``ecc.gear_runout_law``."""
    allowable_um = 0.5 * ecc.gear_runout_um
    if ecc.gear_runout_law == "allowable":
        return allowable_um
    return float(rng.rayleigh(allowable_um / RAYLEIGH_FIELD_SIGMAS))


def ou_process(
    rng: np.random.Generator, n: int, dt_s: float, tau_s: float, sigma: float
) -> np.ndarray:
    """``n`` samples of a stationary OU process with correlation time ``tau_s`` and std ``sigma``."""
    a = math.exp(-dt_s / tau_s)
    eps = rng.standard_normal(n + 1)
    x0 = sigma * eps[0]
    y: np.ndarray
    y, _ = lfilter([sigma * math.sqrt(1 - a * a)], [1.0, -a], eps[1:], zi=[a * x0])
    return y


@dataclass(frozen=True)
class Disturbances:
    """Time-varying plant inputs, as signals in recording time (s)."""

    supply_hz: Signal  # actual VFD output frequency (set-point + jitter)
    rotor_resistance: Signal  # factor, 1 = cold nominal
    torques: dict[str, Signal]  # node -> external torque (N m)
    # roller name -> random phase (rad) of its run-out: the load modulation is
    # -L m sin(2 pi cumsum(rev_hz) dt + phase), the radius r + e sin(theta + phase)
    roller_phase_rad: dict[str, float] = field(default_factory=dict)


def _grid(t_start: float, t_end: float, step: float) -> np.ndarray:
    return t_start + step * np.arange(int(math.ceil((t_end - t_start) / step)) + 2)


def disturbances(
    train: DriveTrain,
    cfg: PlantConfig,
    setpoint: Signal,
    t_start_s: float,
    t_end_s: float,
    streams: dict[str, np.random.Generator],
    *,
    run_up_s: float = 0.0,
    roller_angle_rad: Mapping[str, float] | None = None,
) -> Disturbances:
    """Build every disturbance signal over ``[t_start_s, t_end_s]`` (s, recording time).

    ``run_up_s`` (s) puts the machine's run-up before ``t_start_s``: from rest the supply
    ramps linearly to its first value, the drafting forces act from 5 % of it on at their
    first values, the thermal state holds, no run-out load yet; what follows ``t_start_s`` is
    drawn as without it. ``roller_angle_rad`` (roller name -> rad) are the rollers' angles at
    ``t_start_s``, where each run-out load starts, locked to its roller's angle there."""
    t_sup = _grid(t_start_s, t_end_s, SUPPLY_GRID_S)
    set_hz = setpoint.at(t_sup)
    jitter = ou_process(
        streams["supply"], len(t_sup), SUPPLY_GRID_S, cfg.supply.correlation_s, cfg.supply.jitter_hz
    )
    supply = Signal(t_start_s, SUPPLY_GRID_S, set_hz + jitter * (set_hz > 0))

    th = cfg.thermal
    t_th = _grid(t_start_s, t_end_s, THERMAL_GRID_S)
    warm = th.warmup_kelvin * (
        1 - np.exp(-(t_th - t_start_s + th.elapsed_at_start_s) / th.time_constant_s)
    )
    rotor = Signal(t_start_s, THERMAL_GRID_S, 1.0 + th.resistance_per_kelvin * warm)

    t_f = _grid(t_start_s, t_end_s, FORCE_GRID_S)
    speed_scale = np.interp(t_f, t_sup, set_hz) / max(float(setpoint.values.max()), 1e-9)
    torques = _drafting_torques(train, cfg, t_f, speed_scale, streams["drafting"])
    drafting_at_start = {node: float(tq[0]) for node, tq in torques.items()}
    modulation, phases = _roller_load_modulation(train, cfg, t_f, speed_scale, streams["runout"],
                                                 roller_angle_rad or {})  # fmt: skip
    for node, tq in modulation.items():
        torques[node] = torques.get(node, 0.0) + tq
    signals = {node: Signal(t_start_s, FORCE_GRID_S, tq) for node, tq in torques.items()}
    dist = Disturbances(supply, rotor, signals, phases)
    return _after_run_up(dist, run_up_s, drafting_at_start) if run_up_s > 0 else dist


def _after_run_up(dist: Disturbances, run_up_s: float,
                  drafting_at_start: dict[str, float]) -> Disturbances:  # fmt: skip
    """``dist`` with the run-up's samples put before its signals (see :func:`disturbances`)."""

    def lead(sig: Signal, value: Callable[[np.ndarray], np.ndarray]) -> Signal:
        n = int(round(run_up_s / sig.dt_s))
        frac = np.arange(n) / n  # of the set-point reached, 0 at rest
        return Signal(sig.t0_s - n * sig.dt_s, sig.dt_s, np.concatenate([value(frac), sig.values]))

    first_hz = float(dist.supply_hz.values[0])
    supply = lead(dist.supply_hz, lambda f: f * first_hz)
    rotor = lead(dist.rotor_resistance, lambda f: np.full(len(f), dist.rotor_resistance.values[0]))

    def drafting(node: str) -> Callable[[np.ndarray], np.ndarray]:
        # no sliver is drafted below 5 % of the set-point, as in _drafting_torques
        return lambda f: drafting_at_start.get(node, 0.0) * (f > 0.05)

    torques = {node: lead(sig, drafting(node)) for node, sig in dist.torques.items()}
    return replace(dist, supply_hz=supply, rotor_resistance=rotor, torques=torques)


def _drafting_torques(
    train: DriveTrain,
    cfg: PlantConfig,
    t: np.ndarray,
    speed_scale: np.ndarray,
    rng: np.random.Generator,
) -> dict[str, np.ndarray]:
    """Zone forces (N) -> torques: they brake the delivering roller and drive the feeding one."""
    df = cfg.drafting_force
    n = len(t)
    fast_rng, slow_rng = rng.spawn(2)  # one stream per process keeps shorter runs a prefix
    fluct = math.sqrt(1 - df.slow_share) * ou_process(
        fast_rng, n, FORCE_GRID_S, df.fast_correlation_s, 1.0
    )
    fluct += math.sqrt(df.slow_share) * ou_process(
        slow_rng, n, FORCE_GRID_S, df.slow_correlation_s, 1.0
    )
    running = np.clip(speed_scale, 0.0, 1.0) > 0.05  # no sliver is drafted while stopped
    rollers: dict[str, Roller] = {r.name: r for r in train.spec.roller}
    out: dict[str, np.ndarray] = {}
    for mean, fast, slow in (
        (df.main_zone_mean_n, "front", "second"),
        (df.break_zone_mean_n, "third", "back"),
    ):
        force = mean * (1.0 + df.cv * fluct) * running
        for name, sign in ((fast, -1.0), (slow, 1.0)):
            r = rollers[name]
            out[r.node] = out.get(r.node, 0.0) + sign * force * r.diameter_mm * 5e-4
    return out


def _roller_load_modulation(
    train: DriveTrain,
    cfg: PlantConfig,
    t: np.ndarray,
    speed_scale: np.ndarray,
    rng: np.random.Generator,
    angle_at_start_rad: Mapping[str, float],
) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """Once-per-revolution modulation of each roller's friction load (bottom-roller run-out),
    N m by node, and the random phase (rad) drawn for each roller (by roller name), one draw
    per roller in declaration order. The phase of the load is open loop (the operating
    point's speed times the set-point's scale) from the roller's angle at the start
    (``angle_at_start_rad``, roller name -> rad; 0 where not given), not the simulated
    angle."""
    op = operating_point(train)
    out: dict[str, np.ndarray] = {}
    phases: dict[str, float] = {}
    dt = t[1] - t[0]
    for r in train.spec.roller:
        node = train.node_index(r.node)
        rev_hz = op.node_speed_rad_s[node] / (2 * math.pi) * speed_scale
        phases[str(r.name)] = float(rng.uniform(0, 2 * math.pi))
        start = phases[str(r.name)] + angle_at_start_rad.get(str(r.name), 0.0)
        phase = 2 * math.pi * np.cumsum(rev_hz) * dt + start
        load = r.friction_coefficient * 2 * r.top_load_per_side_n * r.diameter_mm * 5e-4
        out[r.node] = -load * cfg.eccentricity.roller_load_modulation * np.sin(phase)
    return out, phases
