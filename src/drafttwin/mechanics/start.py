"""The state a simulation starts from: standstill, or the steady operating point with the
static deflections of every coupling (shaft twist, belt stretch, mesh deflection and
backlash, chain stretch) under the transmitted torques."""

from __future__ import annotations

import numpy as np

from drafttwin.mechanics import kernel as K
from drafttwin.mechanics.assembly import (
    DriveTrain,
    chain_mean_radius_m,
    chain_pitch_radius_m,
    gear_base_radii_m,
)
from drafttwin.mechanics.components import Belt, ChainDrive, GearMesh, TorsionalCoupling
from drafttwin.mechanics.steady_state import OperatingPoint, operating_point

STOPPED_SUPPLY_HZ = 0.5
"""Below this supply frequency (Hz) the machine counts as stopped and a simulation starts from
rest. A VFD does not start its output below its starting frequency (e.g. the "starting
frequency" parameter Pr. 13 of Mitsubishi FR inverters; 0.5 Hz is an assumed typical setting),
and a torque-balance operating point at a few rpm would sit inside the friction
regularisation of the rollers and bearings."""


def starts_at_rest(train: DriveTrain, t_s: float) -> bool:
    """True if a simulation starting at ``t_s`` (s) starts at standstill: the train has no motor,
    or the motor's supply at ``t_s`` is below :data:`STOPPED_SUPPLY_HZ`."""
    motor = train.spec.motor
    if motor is None:
        return True
    supply = motor.supply_hz if train.supply_hz is None else float(train.supply_hz.at(t_s))
    return supply < STOPPED_SUPPLY_HZ


def static_angles(train: DriveTrain, chain_slack_m: dict[str, float] | None = None,
                  op: OperatingPoint | None = None) -> np.ndarray:  # fmt: skip
    """Node angles (rad, ``train.node_names`` order, motor rotor at 0) at the operating point:
    the static twist of shafts, belt stretch, mesh deflection plus half the backlash (the
    driven gear rests on its loaded flank) and chain stretch. ``chain_slack_m`` adds slack to
    named chains (an elongated chain's driven sprocket trails by half the extra loop length:
    the slack span takes up the other half). Diagnosis compares these between a train and the
    same train with a fault, e.g. a worn mesh's larger backlash. ``op``: the train's
    operating point if already at hand."""
    op = operating_point(train) if op is None else op
    return _initial_state(train, op, chain_slack_m)[: len(train.node_names)]


def _initial_state(train: DriveTrain, op: OperatingPoint,
                   chain_slack_m: dict[str, float] | None = None) -> np.ndarray:  # fmt: skip
    """Steady-speed state with static deflections from the transmitted torques."""
    n = len(train.node_names)
    tab = train.tables()
    nb, nm = tab.belt_i.shape[0], tab.motor_i.shape[0]
    y = np.zeros(2 * n + nb + 2 * nm + K.N_ENERGY)
    y[n : 2 * n] = op.node_speed_rad_s
    belt_row = {b.name: k for k, b in enumerate(train.spec.belt)}
    for e in train.edges:
        c, torque = e.coupling, op.transmitted[e.coupling.name]
        if isinstance(c, TorsionalCoupling):
            sign = 1.0 if c.a == train.node_names[e.parent] else -1.0
            y[e.child] = y[e.parent] - torque / c.stiffness_nm_per_rad * sign
        elif isinstance(c, Belt):
            rb = c.driven_diameter_mm * 5e-4
            y[2 * n + belt_row[c.name]] = torque / rb / c.span_stiffness_n_per_m
            y[e.child] = y[e.parent] * e.ratio
        elif isinstance(c, GearMesh):
            rba, rbb = gear_base_radii_m(c)
            delta = torque / rbb / c.mesh_stiffness_n_per_m + 0.5e-6 * c.backlash_um
            y[e.child] = (rba * y[e.parent] - delta) / rbb
        else:
            rb = chain_pitch_radius_m(c.pitch_mm, c.driven_teeth)
            slack = (chain_slack_m or {}).get(c.name, 0.0)
            stretch = chain_stretch_m(torque / rb, c.pretension_n, c.span_stiffness_n_per_m, slack)
            y[e.child] = _chain_angle_for_feed(c, y[e.parent], stretch)
    y[2 * n + nb : 2 * n + nb + nm] = op.motor_torque_nm
    return y


def chain_stretch_m(force_n: float, pretension_n: float, k_n_per_m: float,
                    slack_m: float = 0.0) -> float:  # fmt: skip
    """Static stretch (m, driver's feed minus driven's) of a chain transmitting ``force_n``
    under the kernel's span law (each span ``max(0, T0 +/- k x)``), with ``slack_m`` of extra
    loop taking ``k slack / 2`` off the pretension (the plant's elongation). While both spans
    stay taut they share the force (``x = F / 2k``: a small elongation is taken up by the
    pretension and moves nothing); once the slack span goes slack the tight one carries it
    all (``x = (F - T0') / k``). Until 2026-11-27 the stretch was ``F / 2k + slack / 2``,
    which left out the pretension: the signature of a 1.1 % elongation came out 2.4 % larger
    than the physics' own step."""
    t0 = pretension_n - 0.5 * k_n_per_m * slack_m
    f = abs(force_n)
    both_taut = f / (2.0 * k_n_per_m)
    x = both_taut if t0 - k_n_per_m * both_taut >= 0.0 else (f - t0) / k_n_per_m
    return -x if force_n < 0.0 else x  # at zero force: resting on the driving flank


def _start_state(train: DriveTrain, t0: float, from_rest: bool) -> np.ndarray:
    """Standstill if asked or if the train is stopped at ``t0``, else the operating point."""
    if from_rest or starts_at_rest(train, t0):
        return _rest_state(train)
    return _initial_state(train, operating_point(train, t=t0))


def _rest_state(train: DriveTrain) -> np.ndarray:
    tab = train.tables()
    n = len(train.node_names)
    return np.zeros(2 * n + tab.belt_i.shape[0] + 2 * tab.motor_i.shape[0] + K.N_ENERGY)


def _chain_angle_for_feed(c: ChainDrive, theta_driver: float, stretch: float) -> float:
    """Driven-sprocket angle whose chain feed trails the driver's by ``stretch`` (Newton)."""
    ra = chain_pitch_radius_m(c.pitch_mm, c.driver_teeth)
    rb = chain_pitch_radius_m(c.pitch_mm, c.driven_teeth)
    target = K._chain_feed(theta_driver, c.driver_teeth, c.pitch_mm * 1e-3, ra)[0] - stretch
    theta: float = target / chain_mean_radius_m(c.pitch_mm, c.driven_teeth)
    for _ in range(20):
        x, dx = K._chain_feed(theta, c.driven_teeth, c.pitch_mm * 1e-3, rb)
        theta -= (x - target) / dx
    return theta
