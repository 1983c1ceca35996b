"""Which file column feeds which channel: declared outputs and inputs, mapping, units.

The caller declares the output channels (default: the four FA320A rollers), the exogenous
inputs (default: set-point columns ``setpoint_*`` and ``supply_hz`` found in the file) and
their units. Header names match case-insensitively and may carry a unit (``y [m]``,
``front_rpm``); ``columns`` maps other names (``{"v1": "front"}``).
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from drafttwin._constants import ROLLERS
from drafttwin.data import validate as v
from drafttwin.data.units import is_rpm, resolve_unit
from drafttwin.errors import ConfigError, DataError

RECORD = "record"
"""Name of the optional integer column that numbers the records (experiments) of a file."""

RESERVED: frozenset[str] = frozenset(
    {"time", "motor", RECORD, v.IGNORE, *v.TIME_NAMES, *v.MOTOR_NAMES}
)


@dataclass(frozen=True)
class ChannelSpec:
    """What the caller declared.

    Attributes:
        outputs: output channel names, in order.
        inputs: exogenous input names, or ``None`` to take the set-point columns of the file.
        units: declared unit per output, input or ``motor``.
        rollers: whether the outputs are the default four rollers.
        setpoints: with declared ``inputs``, also take the file's set-point columns.
    """

    outputs: tuple[str, ...] = ROLLERS
    inputs: tuple[str, ...] | None = None
    units: dict[str, str] = field(default_factory=dict)
    rollers: bool = True
    setpoints: bool = False

    def auto_setpoints(self) -> bool:
        """Whether set-point columns (``setpoint_*``, ``supply_hz``) are read as inputs."""
        return self.inputs is None or self.setpoints

    def declared(self) -> dict[str, str]:
        """Lower-case name -> name, for every declared output and input."""
        return {n.lower(): n for n in (*self.outputs, *(self.inputs or ()))}


def _names(values: Sequence[str] | None, option: str) -> tuple[str, ...]:
    if isinstance(values, str):
        raise ConfigError(
            f"{option} must be a list of names, got the string '{values}'",
            where=option,
            fix=f'write {option}=["{values}"]',
        )
    names = tuple(str(n).strip() for n in values or ())
    seen: set[str] = set()
    for name in names:
        low = name.lower()
        if not name or low in RESERVED:
            raise ConfigError(
                f"'{name}' cannot name an {option[:-1]} channel"
                + (
                    " (it is reserved for the time, motor, record or ignored columns)"
                    if name
                    else ""
                ),
                where=option,
                fix="name the channel differently and map the file column to it with "
                "--columns column=name",
            )
        if low in seen:
            raise ConfigError(f"'{name}' is named twice", where=option, fix="name it once")
        seen.add(low)
    return names


def channel_spec(
    outputs: Sequence[str] | None = None,
    inputs: Sequence[str] | None = None,
    units: Mapping[str, str] | None = None,
    setpoints: bool = False,
) -> ChannelSpec:
    """Check and normalise the declared outputs, inputs and units (``ConfigError`` if wrong)."""
    outs = ROLLERS if outputs is None else _names(outputs, "outputs")
    ins = None if inputs is None else _names(inputs, "inputs")
    if not outs and not ins:  # a file of inputs alone (set-points to simulate) is fine
        raise ConfigError("no output channels declared", where="outputs", fix="name at least one")
    both = {n.lower() for n in outs} & {n.lower() for n in ins or ()}
    if both:
        raise ConfigError(
            f"'{sorted(both)[0]}' is declared both as an output and as an input",
            where="outputs / inputs",
            fix="a column is either a measured output or a known input: declare it once",
        )
    spec = ChannelSpec(outputs=outs, inputs=ins, rollers=outputs is None)
    declared = {**spec.declared(), "motor": "motor"}
    resolved: dict[str, str] = {}
    for key, unit in (units or {}).items():
        name = declared.get(str(key).strip().lower())
        if name is None and (ins is None or setpoints) and _is_setpoint(str(key).strip().lower()):
            name = str(key).strip().lower()
        if name is None:
            raise ConfigError(
                f"units names '{key}', which is neither an output nor an input",
                where="units",
                fix=f"give units for the declared channels: {', '.join(declared)}",
            )
        if name == "motor" and not is_rpm(unit):
            raise ConfigError(
                f"the motor speed must be in rpm, units gives '{unit}'",
                where="units",
                fix="convert the motor column to rpm, or read it as an output of its own",
            )
        resolved[name] = str(unit).strip()
    return ChannelSpec(outputs=outs, inputs=ins, units=resolved, rollers=spec.rollers,
                       setpoints=setpoints)  # fmt: skip


@dataclass
class ColumnPlan:
    """Which file column feeds which channel of a :class:`MeasurementSeries`."""

    time: str
    time_scale: float
    outputs: dict[str, str]  # output channel -> file column, in channel order
    inputs: dict[str, str] = field(default_factory=dict)  # input name -> file column
    motor: str | None = None
    record: str | None = None
    units: dict[str, str] = field(default_factory=dict)  # channel, input or motor -> unit
    unknown: list[str] = field(default_factory=list)
    ignored: list[str] = field(default_factory=list)

    def used(self) -> dict[str, str]:
        """File column -> channel name (or ``time``, ``motor``, ``record``), for provenance."""
        out = {self.time: "time", **{c: r for r, c in self.outputs.items()}}
        if self.motor:
            out[self.motor] = "motor"
        out.update({c: s for s, c in self.inputs.items()})
        if self.record:
            out[self.record] = RECORD
        return out

    def roles(self) -> dict[str, str]:
        """Channel, ``motor`` and input name -> file column (the numeric data columns)."""
        roles = dict(self.outputs)
        if self.motor:
            roles["motor"] = self.motor
        roles.update(self.inputs)
        return roles


_UNIT_RE = re.compile(r"^(.*?)\s*[\[(]\s*([^\])]+?)\s*[\])]$")


def split_unit(name: str) -> tuple[str, str | None]:
    """``'Front [rpm]'`` -> ``('front', 'rpm')``; ``'y (m)'`` -> ``('y', 'm')``;
    ``'front_rpm'`` -> ``('front', 'rpm')``. The name is lower-cased, the unit kept as written."""
    name = name.strip()
    m = _UNIT_RE.match(name)
    if m:
        return m.group(1).strip().lower(), m.group(2).replace(" ", "")
    low = name.lower()
    if low.endswith("_rpm") and len(low) > 4:
        return low[:-4], "rpm"
    return low, None


_TIME_SUFFIX_RE = re.compile(r"^(.+?)_(s|sec|ms|msec|us|usec|min)$")


def time_header(name: str) -> tuple[str, str | None]:
    """A time column's name and unit: ``'time [ms]'`` -> ``('time', 'ms')``, and a unit
    suffix too, ``'time_ms'`` -> ``('time', 'ms')``, ``'zeit_min'`` -> ``('zeit', 'min')``
    (read as seconds before: a millisecond clock made every step 1000x too long)."""
    base, unit = split_unit(name)
    m = _TIME_SUFFIX_RE.match(base) if unit is None else None
    return (m.group(1), m.group(2)) if m else (base, unit)


def _is_setpoint(base: str) -> bool:
    return base.startswith("setpoint_") or base == "supply_hz"


def _target(name: str, spec: ChannelSpec) -> str | None:
    """The channel a (lower-case) name stands for, or ``None``."""
    declared = spec.declared()
    if name in declared:
        return declared[name]
    if name in ("time", "motor", RECORD, v.IGNORE):
        return name
    if spec.auto_setpoints() and _is_setpoint(name):
        return name
    return None


def _mapping_targets(
    columns: Mapping[str, str],
    headers: Sequence[str],
    spec: ChannelSpec,
    source: str | Path,
    option: str = "--columns",
) -> dict[str, str]:
    """Resolve a user mapping {file column: target} against the headers (case-insensitive);
    ``option`` is the one that named it (errors name it)."""
    by_lower = {h.strip().lower(): h for h in headers}
    out: dict[str, str] = {}
    for key, target in columns.items():
        header = key if key in headers else by_lower.get(key.strip().lower())
        if header is None:
            raise DataError(
                f"column '{key}' is not in the file",
                source=source,
                where=option,
                fix=f"the file's columns are: {', '.join(headers)}",
            )
        tgt = _target(target.strip().lower(), spec)
        if tgt is None:
            allowed = (*spec.outputs, *(spec.inputs or ()), "time", "motor", RECORD, v.IGNORE)
            setpoints = ", or a name starting with 'setpoint_'" if spec.auto_setpoints() else ""
            raise DataError(
                f"unknown target '{target}' for column '{key}'",
                source=source,
                where="--columns",
                fix=f"map to one of {', '.join(allowed)}{setpoints}",
            )
        out[header] = tgt
    return out


def _default_target(base: str, spec: ChannelSpec) -> str | None:
    declared = spec.declared()
    if base in declared:
        return declared[base]
    if base in v.TIME_NAMES:
        return "time"
    if base in v.MOTOR_NAMES:
        return "motor"
    if spec.auto_setpoints() and _is_setpoint(base):
        return base
    if base == RECORD:
        return RECORD
    return None


def _time_target(header: str) -> str | None:
    """``"time"`` for a time name with a unit suffix (``time_ms``, ``t_min``)."""
    return "time" if time_header(header)[0] in v.TIME_NAMES else None


def _assign(
    headers: list[str], mapping: dict[str, str], spec: ChannelSpec, source: str | Path
) -> tuple[dict[str, str], list[str]]:
    """Target -> header for every recognised column, and the unrecognised headers."""
    assigned: dict[str, str] = {}
    unknown: list[str] = []
    explicit = [(h, t) for h, t in mapping.items() if t != v.IGNORE]
    defaults = [(h, _default_target(split_unit(h)[0], spec) or _time_target(h))
                for h in headers if h not in mapping]  # fmt: skip
    for h, target in explicit + defaults:
        if target is None or (
            target in assigned and assigned[target] in mapping and h not in mapping
        ):
            unknown.append(h)  # unrecognised, or its default role is taken by a mapped column
        elif target in assigned:
            raise DataError(
                f"two columns give '{target}': '{assigned[target]}' and '{h}'",
                source=source,
                where=f"column '{h}'",
                fix=f"remove one, or drop it on reading with --columns '{h}'=ignore",
            )
        else:
            assigned[target] = h
    return assigned, [h for h in headers if h in unknown]


def plan_columns(
    headers: Sequence[str],
    source: str | Path,
    spec: ChannelSpec | None = None,
    *,
    columns: Mapping[str, str] | None = None,
    time_column: str | None = None,
    stored_units: Mapping[str, str] | None = None,
) -> ColumnPlan:
    """Assign every file column to time, an output, motor, an input, ``record`` or ``unknown``,
    and resolve each channel's unit (``stored_units``: units kept in the file, by column)."""
    spec = spec or ChannelSpec()
    headers = [str(h) for h in headers]
    mapping = _mapping_targets(columns or {}, headers, spec, source)
    if time_column is not None:
        mapping.update(_mapping_targets({time_column: "time"}, headers, spec, source,
                                        option="--time-column"))  # fmt: skip
    assigned, unknown = _assign(headers, mapping, spec, source)
    v.check_time_present(assigned, headers, source)
    kind = "roller" if spec.rollers else "output"
    v.check_channels_present(assigned, headers, spec.outputs, source, kind)
    if spec.inputs is not None:
        v.check_channels_present(assigned, headers, spec.inputs, source, "input")
    inputs = list(spec.inputs or ())
    if spec.auto_setpoints():
        inputs += [t for t in assigned if _is_setpoint(t) and t not in spec.declared().values()]
    units = {}
    for name in (*spec.outputs, *inputs, *(["motor"] if "motor" in assigned else [])):
        header = assigned[name]
        header_unit = split_unit(header)[1] or (stored_units or {}).get(header)
        units[name] = resolve_unit(name, header, header_unit, spec.units.get(name), source)
    time_unit = time_header(assigned["time"])[1]
    return ColumnPlan(
        time=assigned["time"],
        time_scale=v.time_scale(assigned["time"], time_unit and time_unit.lower(), source),
        outputs={r: assigned[r] for r in spec.outputs},
        inputs={name: assigned[name] for name in inputs},
        motor=assigned.get("motor"),
        record=assigned.get(RECORD),
        units=units,
        unknown=unknown,
        ignored=[h for h in headers if mapping.get(h) == v.IGNORE],
    )
