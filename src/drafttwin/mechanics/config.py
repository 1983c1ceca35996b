"""Reading and validating a drive-train declaration (TOML) into a :class:`TrainSpec`.

Every problem becomes one :class:`~drafttwin.errors.ConfigError` naming the file, the component
and the field, and saying what to do.
"""

from __future__ import annotations

import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, ValidationError, model_validator

from drafttwin.errors import ConfigError, unknown_choice
from drafttwin.mechanics.components import (
    COUPLING_KINDS,
    LIST_KINDS,
    SINGLE_KINDS,
    BearingFriction,
    Belt,
    ChainDrive,
    DraftingZone,
    GearMesh,
    InductionMotor,
    Inertia,
    InputChannel,
    OutputChannel,
    Roller,
    Shaft,
    Solver,
    TorqueSeries,
    TorsionalCoupling,
    TrainInfo,
)

PRESETS = ("fa320a",)


class TrainSpec(BaseModel):
    """A whole validated drive train: nodes, couplings, sources and loads, solver settings.

    Couplings of kinds added by :func:`~drafttwin.mechanics.components.register_coupling`
    are held as extra fields of their kind's name (``spec.flexible_coupling``); any other
    extra name is refused."""

    model_config = ConfigDict(extra="allow", frozen=True)

    train: TrainInfo = TrainInfo()
    motor: InductionMotor | None = None
    inertia: list[Inertia]
    belt: list[Belt] = []
    chain: list[ChainDrive] = []
    gear: list[GearMesh] = []
    shaft: list[Shaft] = []
    roller: list[Roller] = []
    drafting_zone: list[DraftingZone] = []
    bearing: list[BearingFriction] = []
    torque: list[TorqueSeries] = []
    input: list[InputChannel] = []
    output: list[OutputChannel] = []
    solver: Solver = Solver()

    @property
    def root_node(self) -> str:
        """The node speed ratios are measured from: the motor's, else the first inertia."""
        return self.motor.node if self.motor is not None else self.inertia[0].name

    @model_validator(mode="before")
    @classmethod
    def _registered_kinds(cls, data: Any) -> Any:
        """Validate the tables of registered coupling kinds; refuse other unknown names."""
        if not isinstance(data, dict):
            return data
        out = dict(data)
        for kind in set(data) - set(cls.model_fields):
            klass = COUPLING_KINDS.get(kind)
            if klass is None:
                raise ValueError(f"unknown component type '{kind}'")
            out[kind] = [c if isinstance(c, klass) else klass.model_validate(c) for c in data[kind]]
        return out

    def couplings(self) -> list[tuple[str, Belt | ChainDrive | GearMesh | TorsionalCoupling]]:
        """All couplings with their kind, in declaration order per kind (built-in kinds first,
        then registered ones)."""
        extra = self.model_extra or {}
        return [(kind, c) for kind in COUPLING_KINDS
                for c in (getattr(self, kind) if kind in type(self).model_fields
                          else extra.get(kind, []))]  # fmt: skip

    def springs(self) -> list[TorsionalCoupling]:
        """The torsional couplings (shafts, then registered kinds): the kernel's spring rows."""
        return [c for _, c in self.couplings() if isinstance(c, TorsionalCoupling)]


def output_target(spec: TrainSpec, name: str) -> tuple[str, float | None]:
    """Node and roller diameter (mm) an output's ``node`` field refers to.

    A node name is taken first; otherwise a roller name means that roller's node. The
    diameter is the one roller on that node (``None`` if it carries none or several of
    different diameters). Raises KeyError if ``name`` is neither.
    """
    nodes = [n.name for n in spec.inertia]
    if name in nodes:
        diameters = {r.diameter_mm for r in spec.roller if r.node == name}
        return name, diameters.pop() if len(diameters) == 1 else None
    for r in spec.roller:
        if r.name == name:
            return r.node, r.diameter_mm
    raise KeyError(name)


def _component_label(raw: dict[str, Any], loc: tuple[Any, ...]) -> tuple[str, str]:
    """('gear 'A-B'' , 'field') from a pydantic error location into the raw document."""
    kind = str(loc[0]) if loc else "document"
    if kind in LIST_KINDS and len(loc) > 1 and isinstance(loc[1], int):
        items = raw.get(kind) or []
        item = items[loc[1]] if loc[1] < len(items) and isinstance(items[loc[1]], dict) else {}
        label = item.get("name") or item.get("channel") or item.get("node") or f"#{loc[1] + 1}"
        field = ".".join(str(p) for p in loc[2:])
        return f"{kind} '{label}'", field
    return f"[{kind}]", ".".join(str(p) for p in loc[1:])


def _translate(
    exc: ValidationError, raw: dict[str, Any], source: str, prefix: tuple[Any, ...] = ()
) -> ConfigError:
    err = exc.errors()[0]
    where, field = _component_label(raw, (*prefix, *err["loc"]))
    kind = err["type"]
    got = err.get("input")
    told = 1  # problems this message names
    if kind == "missing" and not field:  # a whole section (an empty file lacks them all)
        where = f"[[{where[1:-1]}]]" if where[1:-1] in LIST_KINDS else where
        problem = (
            f"no {where} declared"
            if any(raw.values())
            else "the file declares no drive train (no inertias, couplings or rollers)"
        )
        fix = (
            f"declare the train's {where} tables (docs/mechanics.md lists every section; "
            "--preset fa320a is a complete train)"
        )
    elif kind == "missing":
        problem = f"field '{field}' is missing"
        fix = f"add '{field} = ...' to {where} (see docs/mechanics.md for fields and units)"
        # a misspelt required field reads as missing: name the unknown one beside it
        here = tuple(err["loc"][:-1])
        typos = [str(e["loc"][-1]) for e in exc.errors()
                 if e["type"] == "extra_forbidden" and tuple(e["loc"][:-1]) == here]  # fmt: skip
        if typos:
            told += len(typos)
            problem += f", and {', '.join(repr(t) for t in typos)} is not a field"
            fix = f"correct the spelling of {typos[0]!r} to {field!r}" if len(typos) == 1 else fix
    elif kind == "extra_forbidden":
        problem = f"unknown field '{field}'"
        fix = "remove it or correct its spelling (see docs/mechanics.md for the field list)"
    elif kind == "literal_error":
        problem = f"field '{field}' is {got!r}, which is not an allowed value"
        fix = f"use {err.get('ctx', {}).get('expected', 'one of the documented values')}"
    else:
        shown = f" (got {got!r})" if not isinstance(got, dict | list) else ""
        problem = f"field '{field}': {err['msg']}{shown}" if field else f"{err['msg']}{shown}"
        fix = "correct the value; units are in the field name"
    more = len(exc.errors()) - told
    if more:
        problem += f" (and {more} more problem{'s' if more > 1 else ''})"
    return ConfigError(problem, source=source, where=where, fix=fix)


def _check_graph(spec: TrainSpec, source: str) -> None:
    names = [n.name for n in spec.inertia]
    dupes = {n for n in names if names.count(n) > 1}
    if dupes:
        raise ConfigError(
            f"inertia name(s) {sorted(dupes)} declared twice",
            source=source,
            where="[[inertia]]",
            fix="give every inertia a unique name",
        )
    known = set(names)

    def need(node: str, where: str, field: str) -> None:
        if node not in known:
            raise ConfigError(
                f"field '{field}' names unknown node '{node}'",
                source=source,
                where=where,
                fix=f"use one of the declared inertias: {', '.join(names)}",
            )

    if spec.motor is not None:
        need(spec.motor.node, "[motor]", "node")
    parent = {n: n for n in names}

    def find(n: str) -> str:
        while parent[n] != n:
            parent[n] = parent[parent[n]]
            n = parent[n]
        return n

    for kind, c in spec.couplings():
        a_field, b_field = c.end_fields
        a, b = getattr(c, a_field), getattr(c, b_field)
        need(a, f"{kind} '{c.name}'", a_field)
        need(b, f"{kind} '{c.name}'", b_field)
        if a == b:
            raise ConfigError(
                f"connects node '{a}' to itself",
                source=source,
                where=f"{kind} '{c.name}'",
                fix="a coupling joins two different inertias",
            )
        parent[find(a)] = find(b)
    for kind in ("roller", "bearing", "torque"):
        for item in getattr(spec, kind):
            need(item.node, f"{kind} '{getattr(item, 'name', item.node)}'", "node")
    rollers = [r.name for r in spec.roller]
    if len(set(rollers)) != len(rollers):
        raise ConfigError(
            "a roller name appears twice",
            source=source,
            where="[[roller]]",
            fix="declare each of front, second, third, back once",
        )
    _check_drafting_zones(spec, source)
    root = find(spec.root_node)
    loose = [n for n in names if find(n) != root]
    if loose:
        raise ConfigError(
            f"node(s) {loose} are not connected to the root node '{spec.root_node}'",
            source=source,
            where="drive train",
            fix="connect them with a belt, chain, gear or shaft, or remove them",
        )


def _check_drafting_zones(spec: TrainSpec, source: str) -> None:
    """Each zone joins two different declared rollers."""
    rollers = [r.name for r in spec.roller]
    for z in spec.drafting_zone:
        where = f"drafting_zone '{z.name}'"
        for field in ("delivering", "feeding"):
            if getattr(z, field) not in rollers:
                raise ConfigError(f"field '{field}' names roller '{getattr(z, field)}', which is "
                                  "not declared", source=source, where=where,
                                  fix=f"use one of the declared rollers: {', '.join(rollers)}")  # fmt: skip
        if z.delivering == z.feeding:
            raise ConfigError("delivering and feeding are the same roller", source=source,
                              where=where, fix="a zone lies between two roller pairs")  # fmt: skip


def _input_problem(item: InputChannel, spec: TrainSpec) -> tuple[str, str] | None:
    """``(problem, fix)`` for the first rule an [[input]] table breaks, else ``None``."""
    nodes = [n.name for n in spec.inertia]
    motor = spec.motor.node if spec.motor is not None else None
    torque, supply = item.drives == "torque", item.drives == "supply_hz"
    rules = (
        (item.gain == 0.0, "field 'gain' is 0, so the channel would have no effect",
         "give the scale from the channel's unit to Hz or N m (physical value = gain * "
         "channel + offset)"),
        (torque and item.node is None, "field 'node' is missing: a torque input acts on a node",
         f'add node = "..." naming one of: {", ".join(nodes)}'),
        (torque and item.node is not None and item.node not in nodes,
         f"field 'node' names unknown node '{item.node}'",
         f"use one of the declared inertias: {', '.join(nodes)}"),
        (supply and motor is None, "drives 'supply_hz', but the train has no [motor]",
         'add a [motor] whose VFD this channel sets, or use drives = "torque" with a node'),
        (supply and motor is not None and item.node not in (None, motor),
         f"field 'node' names '{item.node}', but a supply input drives the motor on node "
         f"'{motor}'", "remove 'node' (a supply_hz input always drives the motor)"),
    )  # fmt: skip
    return next(((problem, fix) for broken, problem, fix in rules if broken), None)


def _check_inputs(spec: TrainSpec, source: str) -> None:
    """Each [[input]] drives something that exists: the motor's supply or a known node."""
    for item in spec.input:
        found = _input_problem(item, spec)
        if found is not None:
            raise ConfigError(found[0], source=source, where=f"input '{item.channel}'",
                              fix=found[1])  # fmt: skip
    supplies = [i.channel for i in spec.input if i.drives == "supply_hz"]
    if len(supplies) > 1:
        raise ConfigError(
            f"{len(supplies)} inputs drive 'supply_hz' ({', '.join(supplies)})",
            source=source,
            where="[[input]]",
            fix="keep one: the motor has one supply frequency",
        )


def _check_outputs(spec: TrainSpec, source: str) -> None:
    """Each [[output]] reads a known node or roller, once, in a unit that node can give."""
    inputs = {i.channel for i in spec.input}
    seen: set[str] = set()
    for out in spec.output:
        where = f"output '{out.channel}'"
        if out.channel in seen:
            raise ConfigError(
                f"channel '{out.channel}' is declared twice",
                source=source,
                where="[[output]]",
                fix="give every output channel a unique name",
            )
        seen.add(out.channel)
        if out.channel in inputs:
            raise ConfigError(
                f"channel '{out.channel}' is declared both as an input and as an output",
                source=source,
                where=where,
                fix="a measured column is either an input or an output; rename one",
            )
        try:
            node, diameter = output_target(spec, out.node)
        except KeyError:
            rollers = [r.name for r in spec.roller]
            raise ConfigError(
                f"field 'node' names unknown node '{out.node}'",
                source=source,
                where=where,
                fix=f"use a node ({', '.join(n.name for n in spec.inertia)})"
                + (f" or a roller ({', '.join(rollers)})" if rollers else ""),
            ) from None
        if out.unit == "m/min" and diameter is None:
            raise ConfigError(m_per_min_problem(node), source=source, where=where,
                              fix=M_PER_MIN_FIX)  # fmt: skip


M_PER_MIN_FIX = (
    "name a roller (or a node carrying one roller) as 'node', or use rpm, rad/s or rev/s"
)


def m_per_min_problem(node: str) -> str:
    return (
        f"unit 'm/min' is a roller's surface speed, but node '{node}' does not carry one "
        "roller to take the diameter from"
    )


def spec_from_dict(raw: dict[str, Any], source: str = "<config>") -> TrainSpec:
    """Validate a parsed document (e.g. from TOML) into a :class:`TrainSpec`."""
    known = set(LIST_KINDS) | set(SINGLE_KINDS)
    for key in raw:
        if key not in known:
            raise unknown_choice(f"unknown component type '{key}'", sorted(known),
                                 source=source, where=f"[{key}]")  # fmt: skip
    for key in LIST_KINDS:
        if key in raw and not isinstance(raw[key], list):
            raise ConfigError(
                f"'{key}' must be an array of tables",
                source=source,
                where=f"[{key}]",
                fix=f"write it as [[{key}]] (one block per component)",
            )
    try:
        spec = TrainSpec.model_validate({**raw, **_registered_items(raw, source)})
    except ValidationError as exc:
        raise _translate(exc, raw, source) from None
    _check_graph(spec, source)
    _check_inputs(spec, source)
    _check_outputs(spec, source)
    return spec


def _registered_items(raw: dict[str, Any], source: str) -> dict[str, list[Any]]:
    """The tables of registered coupling kinds, validated (errors named as for built-ins)."""
    out: dict[str, list[Any]] = {}
    for kind in set(raw) - set(TrainSpec.model_fields):
        klass = COUPLING_KINDS[kind]
        out[kind] = []
        for i, item in enumerate(raw[kind]):
            try:
                out[kind].append(item if isinstance(item, klass) else klass.model_validate(item))
            except ValidationError as exc:
                raise _translate(exc, raw, source, (kind, i)) from None
    return out


def load_toml(path: str | Path) -> TrainSpec:
    """Read and validate a drive-train TOML file."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(
            "file not found", source=path, fix="give the path of a drive-train TOML file"
        )
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(
            f"not valid TOML: {exc}", source=path, fix="check the syntax at that line"
        ) from None
    return spec_from_dict(raw, source=str(path))


def preset_path(name: str) -> Path:
    """Path of a built-in preset's TOML file."""
    if name not in PRESETS:
        raise unknown_choice(f"unknown preset '{name}'", PRESETS, where="--preset",
                             fix_also=", or give --config FILE")  # fmt: skip
    return Path(str(resources.files("drafttwin.mechanics") / "presets" / f"{name}.toml"))


__all__ = [
    "PRESETS",
    "TrainSpec",
    "load_toml",
    "preset_path",
    "spec_from_dict",
    "Belt",
    "ChainDrive",
    "GearMesh",
    "Shaft",
    "Roller",
]
