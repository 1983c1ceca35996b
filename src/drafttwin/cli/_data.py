"""Data and channel options shared by ``fit``, ``predict``, ``evaluate`` and ``inspect``."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from drafttwin.cli._options import (
    ColumnsOpt,
    InputsOpt,
    OutputsOpt,
    RateToleranceOpt,
    TimeColumnOpt,
    UnitCheckOpt,
    UnitsOpt,
)
from drafttwin.errors import ConfigError

if TYPE_CHECKING:
    from drafttwin.data.series import MeasurementSeries
    from drafttwin.mechanics import DriveTrain
    from drafttwin.models import BaseModel


def names(text: str | None, option: str) -> tuple[str, ...] | None:
    """``'a, b'`` -> ``('a', 'b')``; ``None`` stays ``None``."""
    if text is None:
        return None
    out = tuple(p.strip() for p in text.split(",") if p.strip())
    if not out:
        raise ConfigError(f"{option} is empty", where=option, fix=f"write {option} a,b")
    return out


def pairs(text: str | None, option: str, example: str = "y=m,u=V") -> dict[str, str]:
    """``'y=m,u=V'`` -> ``{'y': 'm', 'u': 'V'}``."""
    out: dict[str, str] = {}
    for item in (text or "").split(","):
        if not item.strip():
            continue
        key, sep, value = item.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise ConfigError(f"'{item}' is not NAME=VALUE", where=option,
                              fix=f"write {option} {example}")  # fmt: skip
        name = key.strip()
        if name in out:  # the last would silently win
            raise ConfigError(f"{name} is given twice ({name}={out[name]} and {item.strip()})",
                              where=option, fix=f"give each name once: {option} {example}")  # fmt: skip
        out[name] = value.strip()
    return out


@dataclass(frozen=True)
class ChannelOptions:
    """The channel options as typed on the command line (an option group)."""

    outputs: OutputsOpt = None
    inputs: InputsOpt = None
    units: UnitsOpt = None
    time_column: TimeColumnOpt = None
    columns: ColumnsOpt = None
    unit_check: UnitCheckOpt = True
    rate_tolerance: RateToleranceOpt = 0.01

    def parse(self) -> Channels:
        parsed = Channels.parse(self.outputs, self.inputs, self.time_column, self.units)
        return replace(parsed, columns=pairs(self.columns, "--columns", "v1=front,v2=second") or None,
                       check_units=self.unit_check, rate_tolerance=self.rate_tolerance)  # fmt: skip


@dataclass(frozen=True)
class Channels:
    """The channel options as given on the command line."""

    outputs: tuple[str, ...] | None = None
    inputs: tuple[str, ...] | None = None
    time_column: str | None = None
    units: dict[str, str] | None = None
    columns: dict[str, str] | None = None  # file column -> channel / time / motor
    check_units: bool = True
    rate_tolerance: float = 0.01
    nominal_rpm: dict[str, float] | None = None  # the drive train's, to catch rad/s or rev/s

    @classmethod
    def parse(
        cls, outputs: str | None, inputs: str | None, time_column: str | None, units: str | None
    ) -> Channels:
        return cls(names(outputs, "--outputs"), names(inputs, "--inputs"), time_column,
                   pairs(units, "--units") or None)  # fmt: skip

    def for_model(self, model: BaseModel) -> Channels:
        """These options checked against a fitted model: outputs, inputs and units must not
        contradict the model file; what is not given is taken from it."""
        problems = []
        if self.outputs is not None and tuple(self.outputs) != tuple(model.channels_):
            problems.append(f"--outputs {','.join(self.outputs)} (model: "
                            f"{','.join(model.channels_)})")  # fmt: skip
        missing = [n for n in model.task.inputs if n not in (self.inputs or model.task.inputs)]
        if missing:
            problems.append(f"--inputs lacks {','.join(missing)} that the model uses")
        for name, unit in (self.units or {}).items():
            known = model.units_.get(name)
            if known is not None and known != unit:
                problems.append(f"--units {name}={unit} (model: {name}={known or '(none)'})")
        if problems:
            raise ConfigError(
                "the channel options contradict the model file: " + "; ".join(problems),
                where="--outputs / --inputs / --units",
                fix="leave them out to use the model's channels, or fit a model on these",
            )
        units = {k: v for k, v in model.units_.items() if v} | dict(self.units or {})
        inputs = tuple(dict.fromkeys((*model.task.inputs, *(self.inputs or ()))))
        return replace(self, outputs=tuple(model.channels_), inputs=inputs, units=units)

    def for_train(self, train: DriveTrain) -> Channels:
        """These options with a drive-train file's own ``[[output]]`` channels and units
        where none are given (a train that declares none: the FA320A rollers in rpm). A
        ``--units`` entry that contradicts the file's unit for a channel is refused: the
        simulation compares in the file's unit."""
        from drafttwin.data.units import normalise_unit

        declared = {o.channel: o.unit for o in train.spec.output}
        if not declared:
            return self
        wrong = [f"{name}={unit} against the file's {declared[name]}"
                 for name, unit in (self.units or {}).items()
                 if name in declared and normalise_unit(unit) != normalise_unit(declared[name])]  # fmt: skip
        if wrong:
            raise ConfigError(f"{'; '.join(wrong)}: the drive train's [[output]] table "
                              "names another unit", source=train.source, where="--units",
                              fix="leave those channels out of --units (the file gives their "
                              "units), or change the unit in the file's [[output]] table")  # fmt: skip
        outputs = self.outputs or tuple(declared)
        units = {n: declared[n] for n in outputs if n in declared} | dict(self.units or {})
        return replace(self, outputs=outputs, units=units)

    def reading(self, extra_inputs: tuple[str, ...] = ()) -> dict[str, Any]:
        """The keyword arguments of ``read_measurements`` these options ask for (``read`` and
        ``inspect`` both read so)."""
        # a column given a unit is read too (as an input unless it is an output: the rollers
        # where no --outputs are given); the motor column is read in rpm, its unit need not be
        # declared
        from drafttwin.data.units import is_rpm

        units = dict(self.units or {})
        if not is_rpm(units.get("motor", "rpm")):
            raise ConfigError(f"the motor column is read in rpm, not {units['motor']}",
                              where="--units", fix="convert it to rpm, or leave motor out "
                              "of --units")  # fmt: skip
        units.pop("motor", None)
        outputs = self.outputs or _rollers()
        with_units = [n for n in units if n not in outputs]
        inputs = tuple(dict.fromkeys((*(self.inputs or ()), *extra_inputs, *with_units)))
        return {"outputs": self.outputs, "units": units or None, "time_column": self.time_column,
                "inputs": inputs, "setpoints": True, "columns": self.columns,
                "check_units": self.check_units, "rate_tolerance": self.rate_tolerance,
                "nominal_rpm": self.nominal_rpm}  # fmt: skip

    def read(self, spec: str, extra_inputs: tuple[str, ...] = ()) -> MeasurementSeries:
        """The series named by ``--data``/``--test-data``: ``default`` or file(s)."""
        if spec == "default":
            if (self.outputs not in (None, _rollers()) or self.inputs or self.time_column
                    or self.columns):  # fmt: skip
                raise ConfigError(
                    "the embedded default data have the FA320A rollers and supply_hz only",
                    where="--data default",
                    fix="drop the channel options, or pass your own file with --data",
                )
            from drafttwin.datasets import load_default

            return load_default()
        from drafttwin.data.io import read_measurements

        paths = [Path(p.strip()) for p in spec.split(",") if p.strip()]
        kwargs = self.reading(extra_inputs)
        parts = [read_measurements(p, **kwargs) for p in paths]  # plant records: with truth
        if len(parts) == 1:
            return parts[0]
        from drafttwin.data.records import join_files

        return join_files(parts, paths, rate_tolerance=self.rate_tolerance)


def _rollers() -> tuple[str, ...]:
    from drafttwin._constants import ROLLERS

    return ROLLERS


def nominal_rpm(train: DriveTrain) -> dict[str, float]:
    """Each rpm channel's and the motor's speed at the train's rated point: a record's running
    medians are compared with them, so a column in rad/s or rev/s is refused by name."""
    from drafttwin.mechanics import kinematics

    node_rpm = kinematics(train).node_rpm
    speeds = {m.channel: float(node_rpm[m.node]) for m in train.output_channels()
              if m.unit == "rpm" and m.node in node_rpm}  # fmt: skip
    speeds.setdefault("motor", float(node_rpm.get("motor", 0.0)))
    return {name: rpm for name, rpm in speeds.items() if rpm > 0}
