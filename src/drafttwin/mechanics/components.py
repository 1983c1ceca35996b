"""Drive-train components, one small declarative element per physical part.

In the style of Modelica.Mechanics.Rotational: inertias are the nodes; couplings (belt, chain,
gear mesh, shaft torsion) connect two nodes by name; sources and sinks (motor, roller friction
load, drafting force, bearing friction, external torque) act on one node. Every field carries its unit in its
name. These classes hold and check parameters (a coupling also names the two nodes it joins
and its nominal speed ratio); :mod:`drafttwin.mechanics.assembly` turns them into the numeric
tables the integrator uses. A new torsional coupling is one :class:`TorsionalCoupling` subclass
registered with :func:`register_coupling` (``tests/mechanics/test_new_element.py``).

Speed convention: every coupling keeps its driven node turning in the same sense as its driver,
so all speeds in a running train are positive (bottom-roller speeds are magnitudes, as an
encoder reports them).
"""

from __future__ import annotations

import math
from abc import abstractmethod
from typing import Annotated, ClassVar, Literal, get_args

from pydantic import BaseModel, ConfigDict, Field, model_validator

# Physical ranges: every number is finite (``allow_inf_nan=False`` below) and inside a range
# wide enough for any drive train of a textile machine, narrow enough to refuse typos (1e30).
Positive = Annotated[float, Field(gt=0, le=1e12)]
NonNegative = Annotated[float, Field(ge=0, le=1e12)]
InertiaKgm2 = Annotated[float, Field(gt=0, le=1e4)]
PowerW = Annotated[float, Field(gt=0, le=1e7)]
SpeedRpm = Annotated[float, Field(gt=0, le=1e5)]
SupplyHz = Annotated[float, Field(gt=0, le=1000)]
LengthMm = Annotated[float, Field(gt=0, le=1e4)]
Micrometres = Annotated[float, Field(ge=0, le=1e4)]
AngleDeg = Annotated[float, Field(ge=-3600, le=3600)]
ForceN = Annotated[float, Field(ge=0, le=1e6)]
TorqueNm = Annotated[float, Field(ge=-1e6, le=1e6)]
TimeS = Annotated[float, Field(ge=-1e7, le=1e7)]
SpeedEps = Annotated[float, Field(gt=0, le=100)]
DampingRatio = Annotated[float, Field(ge=0, le=2)]
Teeth = Annotated[int, Field(ge=6, le=400)]
RollerName = Literal["front", "second", "third", "back"]
ROLLER_NAMES: tuple[str, ...] = get_args(RollerName)
OutputUnit = Literal["rpm", "rad/s", "rev/s", "m/min"]
OUTPUT_UNITS: tuple[str, ...] = get_args(OutputUnit)


class Component(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)
    """Strict: a TOML ``true`` or ``"50"`` is not a number; ``inf`` and ``nan`` are refused."""


class Inertia(Component):
    """A rigid rotating body (a node of the train)."""

    name: str = Field(min_length=1)
    inertia_kgm2: InertiaKgm2
    note: str = ""


class InductionMotor(Component):
    """Induction motor with a Kloss torque-speed curve and a first-order torque lag.

    ``T_kloss = 2 T_k / (s/s_k + s_k/s)`` with slip ``s = (w_sync - w)/w_sync``,
    ``w_sync = 2 pi f / pole_pairs``, breakdown torque ``T_k = breakdown_torque_ratio * T_n``
    and ``s_k = s_n (lambda + sqrt(lambda^2 - 1))``; ``torque_lag_s * dT/dt = T_kloss - T``.
    ``supply_hz`` is the mains frequency or the VFD set-point.
    """

    node: str
    rated_power_w: PowerW
    rated_rpm: SpeedRpm
    poles: Annotated[int, Field(ge=2, le=24, multiple_of=2)]
    rated_supply_hz: SupplyHz = 50.0
    supply_hz: SupplyHz = 50.0
    breakdown_torque_ratio: Annotated[float, Field(gt=1.0, le=6.0)] = 2.8
    torque_lag_s: Annotated[float, Field(gt=0, le=1.0)] = 0.01
    torque_ripple: Annotated[float, Field(ge=0, le=0.2)] = 0.0
    """Relative torque ripple amplitude at twice the supply frequency."""

    @model_validator(mode="after")
    def _slip_positive(self) -> InductionMotor:
        sync_rpm = 120.0 * self.rated_supply_hz / self.poles
        if not self.rated_rpm < sync_rpm:
            raise ValueError(
                f"rated_rpm {self.rated_rpm} must be below the synchronous speed {sync_rpm:g} rpm "
                f"of a {self.poles}-pole motor at {self.rated_supply_hz:g} Hz"
            )
        return self


class _TwoEnded(Component):
    """An element that joins two nodes, named by its fields ``end_fields``."""

    name: str
    end_fields: ClassVar[tuple[str, str]]

    @property
    def ends(self) -> tuple[str, str]:
        """The nodes it joins, in the order of ``end_fields``."""
        a, b = self.end_fields
        return getattr(self, a), getattr(self, b)


class _Transmission(_TwoEnded):
    """A coupling that drives node ``driven`` from node ``driver``."""

    driver: str
    driven: str
    end_fields: ClassVar[tuple[str, str]] = ("driver", "driven")


class Belt(_Transmission):
    """Flat/V belt: span spring between the pulley rims plus elastic creep.

    Creep ``eps = F / axial_rigidity_n`` (strain difference between tight and slack strand),
    so the driven rim runs ``(1 - eps)`` slower than the driver rim.
    """

    driver_diameter_mm: LengthMm
    driven_diameter_mm: LengthMm
    span_stiffness_n_per_m: Positive
    axial_rigidity_n: Positive
    damping_ratio: DampingRatio = 0.05

    @property
    def speed_ratio(self) -> float:
        """Nominal driven / driver speed (rigid, no creep)."""
        return self.driver_diameter_mm / self.driven_diameter_mm


class _ToothedTransmission(_Transmission):
    """A transmission whose speed ratio is set by tooth counts (chain sprockets, gears)."""

    driver_teeth: Teeth
    driven_teeth: Teeth

    @property
    def speed_ratio(self) -> float:
        """Nominal driven / driver speed."""
        return self.driver_teeth / self.driven_teeth


class ChainDrive(_ToothedTransmission):
    """Roller chain on two sprockets: polygon (chordal) action, compliant spans, pretension.

    Chain feed of a sprocket ``x(theta) = p n + R sin(phi)``, ``R = p / (2 sin(pi/z))``;
    each span carries ``max(0, pretension +/- k (x_driver - x_driven) +/- c d/dt(...))``.
    """

    pitch_mm: LengthMm = 12.7
    span_stiffness_n_per_m: Positive
    pretension_n: ForceN = 150.0
    damping_ratio: DampingRatio = 0.05


class GearMesh(_ToothedTransmission):
    """Spur gear pair: time-varying mesh stiffness, damping, backlash, eccentricity.

    Mesh deflection along the line of action ``delta = r_b1 th1 - r_b2 th2 - e(th1, th2)``;
    force ``F = k(phase) g(delta) + c d(delta)/dt`` in contact, 0 inside the backlash.
    ``k`` alternates between single- and double-pair contact (fraction ``contact_ratio - 1``
    of each mesh cycle in double contact, ``stiffness_ratio = k_double / k_single``), smoothed
    to ``harmonics`` Fourier terms; its mean is ``mesh_stiffness_n_per_m``.
    """

    module_mm: LengthMm = 2.0
    pressure_angle_deg: Annotated[float, Field(gt=10, lt=35)] = 20.0
    mesh_stiffness_n_per_m: Positive = 3.0e8
    contact_ratio: Annotated[float, Field(ge=1.0, le=2.0)] = 1.6
    stiffness_ratio: Annotated[float, Field(ge=1.0, le=3.0)] = 1.7
    harmonics: Annotated[int, Field(ge=0, le=12)] = 5
    backlash_um: Micrometres = 0.0
    """Total backlash 2b along the line of action; DIN 3967 context gives about 0.04 * module."""
    damping_ratio: DampingRatio = 0.05
    driver_eccentricity_um: Micrometres = 0.0
    driven_eccentricity_um: Micrometres = 0.0
    driver_eccentricity_phase_deg: AngleDeg = 0.0
    driven_eccentricity_phase_deg: AngleDeg = 0.0
    transmission_error_um: Micrometres = 0.0
    """Amplitude of the tooth-mesh-frequency transmission error."""


class TorsionalCoupling(_TwoEnded):
    """A linear torsional spring-damper joining nodes ``a`` and ``b``, which turn together: the
    torque ``k (theta_a - theta_b) + c (omega_a - omega_b)`` brakes ``a`` and drives ``b``.

    The one place such an element is written: a subclass declares its fields and
    :meth:`damping_nms`, and :func:`register_coupling` makes it a ``[[kind]]`` of drive-train
    files. The assembly (a row of the kernel's spring table, :meth:`spring_row`), the
    kinematics, the start state and the reduction treat every torsional coupling alike.
    """

    a: str
    b: str
    stiffness_nm_per_rad: Positive
    end_fields: ClassVar[tuple[str, str]] = ("a", "b")

    @property
    def speed_ratio(self) -> float:
        """Nominal b / a speed: both ends turn together."""
        return 1.0

    @abstractmethod
    def damping_nms(self, ja: float, jb: float) -> float:
        """Viscous damping of the twist, N m s/rad, given the inertias at ``a`` and ``b``
        (each coupling its own law: a subclass cannot be built without one)."""

    def spring_row(self, ja: float, jb: float) -> tuple[float, float]:
        """Its row of the kernel's spring table: stiffness (N m/rad), damping (N m s/rad)."""
        return self.stiffness_nm_per_rad, self.damping_nms(ja, jb)


class Shaft(TorsionalCoupling):
    """Torsional spring-damper, e.g. the twist of a bottom roller between drive end and body;
    damped at ``damping_ratio`` of critical for the two inertias it joins."""

    damping_ratio: DampingRatio = 0.05

    def damping_nms(self, ja: float, jb: float) -> float:
        return 2 * self.damping_ratio * math.sqrt(self.stiffness_nm_per_rad * ja * jb / (ja + jb))


class Roller(Component):
    """A measured bottom roller and its friction load from the top-roller pressure.

    Tangential force ``f = mu * 2 * F_N`` (paper eq. 1, both sides) at the roller radius,
    regularised near zero speed as ``tanh(w / friction_speed_eps_rad_s)``.
    """

    name: RollerName
    node: str
    diameter_mm: LengthMm
    top_load_per_side_n: ForceN
    friction_coefficient: Annotated[float, Field(ge=0, le=1)] = 0.1
    friction_speed_eps_rad_s: SpeedEps = 0.5


class DraftingZone(Component):
    """A drafting zone: the sliver between two roller pairs is drawn with ``force_n`` (N).

    The force pulls back the delivering (faster) roller and drives the feeding one, each at
    its radius, regularised near zero speed like the roller friction (no force at
    standstill). The power ``force * (v_delivering - v_feeding)`` goes into drafting.
    """

    name: str
    delivering: RollerName
    feeding: RollerName
    force_n: ForceN
    speed_eps_rad_s: SpeedEps = 0.5


class BearingFriction(Component):
    """Bearing losses on a node: Coulomb torque (tanh-regularised) plus viscous drag."""

    node: str
    coulomb_torque_nm: Annotated[float, Field(ge=0, le=1e6)] = 0.0
    viscous_nms: Annotated[float, Field(ge=0, le=1e6)] = 0.0
    speed_eps_rad_s: SpeedEps = 0.5


class TorqueSeries(Component):
    """External torque on a node from a time series (N m, positive drives the node)."""

    name: str
    node: str
    times_s: list[TimeS] = Field(min_length=2)
    torque_nm: list[TorqueNm] = Field(min_length=2)

    @model_validator(mode="after")
    def _same_length_increasing(self) -> TorqueSeries:
        if len(self.times_s) != len(self.torque_nm):
            raise ValueError(
                f"times_s has {len(self.times_s)} values but torque_nm has {len(self.torque_nm)}"
            )
        if any(b <= a for a, b in zip(self.times_s, self.times_s[1:], strict=False)):
            raise ValueError("times_s must be strictly increasing")
        return self


class InputChannel(Component):
    """A measured input channel that drives the train.

    ``physical = gain * channel + offset``: the motor's supply frequency in Hz
    (``drives = "supply_hz"``) or a torque in N m on ``node`` (``drives = "torque"``, positive
    drives the node). ``hold = "linear"`` ramps between samples (a logged set-point);
    ``"zoh"`` holds each sample until the next (a controller output updated per sample).
    """

    channel: str = Field(min_length=1)
    drives: Literal["supply_hz", "torque"]
    node: str | None = None
    gain: Annotated[float, Field(allow_inf_nan=False)] = 1.0
    offset: Annotated[float, Field(allow_inf_nan=False)] = 0.0
    hold: Literal["linear", "zoh"] = "linear"


class OutputChannel(Component):
    """A measured output channel: the interval-mean speed of one node in ``unit``.

    ``node`` is a node name, or a roller name (front, second, third, back) meaning that
    roller's node. ``m/min`` is the surface speed of a roller (from its diameter).
    """

    channel: str = Field(min_length=1)
    node: str = Field(min_length=1)
    unit: OutputUnit = "rpm"


class Solver(Component):
    """Integrator settings: fixed-step RK4, interval-mean output."""

    dt_s: Annotated[float, Field(ge=1e-7, le=1e-3)] = 2.0e-5
    output_rate_hz: Annotated[float, Field(gt=0, le=100_000)] = 1000.0
    settle_s: Annotated[float, Field(ge=0, le=3600)] = 1.0


class TrainInfo(Component):
    name: str = "drive-train"
    description: str = ""


COUPLING_KINDS: dict[str, type[Component]] = {
    "belt": Belt,
    "chain": ChainDrive,
    "gear": GearMesh,
    "shaft": Shaft,
}
LIST_KINDS: dict[str, type[Component]] = {
    "inertia": Inertia,
    **COUPLING_KINDS,
    "roller": Roller,
    "drafting_zone": DraftingZone,
    "bearing": BearingFriction,
    "torque": TorqueSeries,
    "input": InputChannel,
    "output": OutputChannel,
}
SINGLE_KINDS = {"train": TrainInfo, "motor": InductionMotor, "solver": Solver}
BUILT_IN_KINDS = frozenset(LIST_KINDS) | frozenset(SINGLE_KINDS)


def register_coupling(kind: str, cls: type[TorsionalCoupling]) -> type[TorsionalCoupling]:
    """Make ``cls`` (a :class:`TorsionalCoupling` subclass) the ``[[kind]]`` tables of
    drive-train files and dicts: a new coupling element, written in its one class. Returns
    ``cls``; :func:`unregister_coupling` takes it back."""
    if not (isinstance(cls, type) and issubclass(cls, TorsionalCoupling)):
        raise TypeError(f"{cls!r} is not a TorsionalCoupling subclass")
    if kind in BUILT_IN_KINDS or LIST_KINDS.get(kind, cls) is not cls:
        raise ValueError(f"component type '{kind}' is taken by {LIST_KINDS.get(kind)}")
    if not kind.isidentifier():
        raise ValueError(f"component type '{kind}' is not a TOML-friendly name")
    COUPLING_KINDS[kind] = LIST_KINDS[kind] = cls
    return cls


def unregister_coupling(kind: str) -> None:
    """Forget a coupling :func:`register_coupling` added (built-in kinds stay)."""
    if kind in BUILT_IN_KINDS:
        raise ValueError(f"component type '{kind}' is built in")
    COUPLING_KINDS.pop(kind, None)
    LIST_KINDS.pop(kind, None)
