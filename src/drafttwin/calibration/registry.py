"""The physical parameters a calibration may estimate, by the plant's dotted names.

Each parameter is a field (or a few fields moved together) of one component in a drive
train's declaration, named as the plant emulator's sidecar names its ``mismatch_draws``:

* ``roller.<name>.friction_coefficient``, ``drafting_zone.<name>.force_n`` (the sliver's
  drafting force), ``bearing.<node>`` (Coulomb and viscous friction
  together, as a factor on the declared values),
* ``belt.<name>.axial_rigidity_n`` (creep), ``belt.<name>.damping_ratio``,
* ``chain.<name>.span_stiffness_n_per_m``, ``gear.<name>.mesh_stiffness_n_per_m``,
  ``shaft.<name>.stiffness_nm_per_rad``,
* ``motor.breakdown_torque_ratio``, ``motor.rated_slip`` (the slip at rated torque, which
  scales with the rotor resistance and so carries the motor's thermal state; stored in the
  declaration as ``rated_rpm``).

The fit works on factors ``x = value / nominal`` (1 = the drawing's value), which puts every
parameter on one scale.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import BaseModel

from drafttwin.errors import ConfigError
from drafttwin.mechanics import DriveTrain

Raw = dict[str, Any]
_MARGIN = 1e-6
"""How far inside an open bound (``gt``, ``lt``) the fit stays, relative."""


@dataclass(frozen=True)
class Parameter:
    """One calibratable parameter of a drive-train declaration.

    Attributes:
        name: dotted name (``roller.front.friction_coefficient``).
        unit: unit of :meth:`value` (``""`` for factors).
        default: part of the default set (what a user cannot read off a drawing).
        get / put: read the value from, and write it into, a raw declaration (dict).
        valid: the values the declaration accepts (its fields' bounds), a closed interval:
            the fit keeps the parameter inside it.
    """

    name: str
    unit: str
    default: bool
    get: Callable[[Raw], float]
    put: Callable[[Raw, float], None]
    valid: tuple[float, float] = (-math.inf, math.inf)

    def value(self, raw: Raw) -> float:
        return float(self.get(raw))

    def factor_range(self, nominal: float, widest: tuple[float, float]) -> tuple[float, float]:
        """The factors on ``nominal`` the fit may take: ``widest`` cut to :attr:`valid` (a
        factor on a zero or negative nominal moves nothing, or flips sign: ``widest``)."""
        low, high = widest
        if nominal > 0:
            low, high = max(low, self.valid[0] / nominal), min(high, self.valid[1] / nominal)
        return min(low, 1.0), max(high, 1.0)  # the nominal itself is always allowed


def _field(kind: str, index: int, key: str) -> tuple[Callable[[Raw], float], Callable[[Raw, float], None]]:  # fmt: skip
    def get(raw: Raw) -> float:
        return float(raw[kind][index][key])

    def put(raw: Raw, value: float) -> None:
        raw[kind][index][key] = value

    return get, put


def _bearing(indices: Sequence[int]) -> tuple[Callable[[Raw], float], Callable[[Raw, float], None]]:  # fmt: skip
    """The friction of a node's bearings (every ``[[bearing]]`` table on it: a process load
    declared as a second bearing is its largest share) as one factor on their declared
    Coulomb and viscous values; the nominal values travel in the raw dict under a private
    key."""

    def get(raw: Raw) -> float:
        return float(raw["bearing"][indices[0]].get("_scale", 1.0))

    def put(raw: Raw, value: float) -> None:
        for index in indices:
            item = raw["bearing"][index]
            base = item.setdefault("_nominal", (item.get("coulomb_torque_nm", 0.0),
                                                item.get("viscous_nms", 0.0)))  # fmt: skip
            item["_scale"] = value
            item["coulomb_torque_nm"], item["viscous_nms"] = base[0] * value, base[1] * value

    return get, put


def _rated_slip(raw: Raw) -> float:
    m = raw["motor"]
    synchronous_rpm = 120.0 * m.get("rated_supply_hz", 50.0) / m["poles"]
    slip: float = 1.0 - float(m["rated_rpm"]) / synchronous_rpm
    return slip


def _set_rated_slip(raw: Raw, slip: float) -> None:
    m = raw["motor"]
    m["rated_rpm"] = (1.0 - slip) * 120.0 * m.get("rated_supply_hz", 50.0) / m["poles"]


_TABLES: tuple[tuple[str, str, str, str, bool], ...] = (
    # kind, name key, field, unit, in the default set
    ("roller", "name", "friction_coefficient", "", True),
    ("drafting_zone", "name", "force_n", "N", True),
    ("belt", "name", "axial_rigidity_n", "N", True),
    ("belt", "name", "damping_ratio", "", True),
    ("chain", "name", "span_stiffness_n_per_m", "N/m", True),
    ("gear", "name", "mesh_stiffness_n_per_m", "N/m", True),
    ("shaft", "name", "stiffness_nm_per_rad", "N m/rad", True),
)


def parameters(train: DriveTrain) -> dict[str, Parameter]:
    """Every calibratable parameter of ``train`` by dotted name, in declaration order."""
    raw = train.to_dict()
    out: dict[str, Parameter] = {}
    for kind, key, field, unit, default in _TABLES:
        for i, item in enumerate(raw.get(kind, [])):
            name = f"{kind}.{item[key]}.{field}"
            valid = _valid(type(getattr(train.spec, kind)[i]), field)
            out[name] = Parameter(name, unit, default, *_field(kind, i, field), valid=valid)
    on_node: dict[str, list[int]] = {}
    for i, item in enumerate(raw.get("bearing", [])):
        on_node.setdefault(item["node"], []).append(i)
    for node, indices in on_node.items():
        out[f"bearing.{node}"] = Parameter(f"bearing.{node}", "", True, *_bearing(indices),
                                           valid=(0.0, math.inf))  # fmt: skip
    if train.spec.motor is not None:
        ratio = "breakdown_torque_ratio"
        out[f"motor.{ratio}"] = Parameter(f"motor.{ratio}", "", True, *_field_motor(ratio),
                                          valid=_valid(type(train.spec.motor), ratio))  # fmt: skip
        # rated_rpm in (0, synchronous): the slip in (0, 1)
        out["motor.rated_slip"] = Parameter("motor.rated_slip", "", True, _rated_slip,
                                            _set_rated_slip, valid=_inside(0.0, 1.0))  # fmt: skip
    return out


def _inside(low: float, high: float) -> tuple[float, float]:
    """A closed interval just inside the open one ``(low, high)``."""
    return low + _MARGIN * max(abs(low), 1.0), high - _MARGIN * max(abs(high), 1.0)


def _valid(component: type[BaseModel], field: str) -> tuple[float, float]:
    """The values the declaration's validation accepts for ``component.field``, as a closed
    interval (an open end moved just inside), from the field's own bounds."""
    low, high = -math.inf, math.inf
    for bound in component.model_fields[field].metadata:  # pydantic's Ge, Gt, Le, Lt
        if (ge := getattr(bound, "ge", None)) is not None:
            low = max(low, float(ge))
        if (gt := getattr(bound, "gt", None)) is not None:
            low = max(low, _inside(float(gt), math.inf)[0])
        if (le := getattr(bound, "le", None)) is not None:
            high = min(high, float(le))
        if (lt := getattr(bound, "lt", None)) is not None:
            high = min(high, _inside(-math.inf, float(lt))[1])
    return low, high


def _field_motor(key: str) -> tuple[Callable[[Raw], float], Callable[[Raw, float], None]]:
    def get(raw: Raw) -> float:
        return float(raw["motor"][key])

    def put(raw: Raw, value: float) -> None:
        raw["motor"][key] = value

    return get, put


def select(train: DriveTrain, names: Sequence[str] | None) -> list[Parameter]:
    """The parameters named (``None``: the default set), refusing unknown names."""
    known = parameters(train)
    if names is None:
        return [p for p in known.values() if p.default]
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ConfigError(
            f"unknown parameter(s) {unknown} for drive train {train.spec.train.name}",
            where="--params",
            fix=f"use names like {', '.join(list(known)[:4])} (all: {len(known)}; see "
            "docs/calibration.md)",
        )
    return [known[n] for n in dict.fromkeys(names)]


def with_factors(
    train: DriveTrain, params: Sequence[Parameter], factors: Sequence[float] | np.ndarray
) -> DriveTrain:
    """A copy of ``train`` with each parameter at ``factor * nominal`` (re-validated)."""
    raw = copy.deepcopy(train.to_dict())
    nominal = [p.value(raw) for p in params]
    for p, value, f in zip(params, nominal, factors, strict=True):
        p.put(raw, value * float(f))
    for item in raw.get("bearing", []):
        item.pop("_scale", None), item.pop("_nominal", None)
    return DriveTrain.from_dict(raw, source=str(train.source))


def nominal_values(train: DriveTrain, params: Sequence[Parameter]) -> list[float]:
    raw = train.to_dict()
    return [p.value(raw) for p in params]
