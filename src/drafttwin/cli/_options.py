"""The options that several commands share, each declared once as an ``Annotated`` type.

A command takes an option by annotating a parameter with its type (``quiet: QuietOpt =
False``); the parameter's default is the option's default. The factories below build the
``typer.Option`` of each kind of option with its check: a numeric option's range
(:func:`number`, ranges in :mod:`drafttwin.cli._bounds`), an input or output path named in
messages about it (:func:`file_in`, :func:`path_in`, :func:`files_in`, :func:`file_out`,
:func:`dir_out`, callbacks in :mod:`drafttwin.cli._oserrors`). Options that always come
together form a group (:class:`TrainOptions`, see :mod:`drafttwin.cli._groups`).

Options of one command are declared at the top of its module with the same factories; those
the commands of one group share, in the group's module (``twin_cmds.py``, ``sliver_cmds.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from drafttwin.cli._bounds import bounded
from drafttwin.cli._common import load_train
from drafttwin.cli._oserrors import (
    input_path,
    input_paths,
    output_dir,
    output_file,
    physics_paths,
)

if TYPE_CHECKING:
    from drafttwin.mechanics import DriveTrain


def number(flag: str, help: str, **kw: Any) -> Any:
    """A numeric option, refused out of its range (``BOUNDS[flag]``) while parsing."""
    return typer.Option(flag, help=help, callback=bounded(flag), **kw)


def file_in(flag: str, help: str) -> Any:
    """An input file (a folder is refused); an unreadable one gets one message from the
    read (cli/_oserrors.py), not click's."""
    return typer.Option(flag, help=help, dir_okay=False, readable=False, callback=input_path(flag))


def path_in(flag: str, help: str) -> Any:
    """An input file or folder."""
    return typer.Option(flag, help=help, callback=input_path(flag))


def files_in(flag: str, help: str) -> Any:
    """Input files, comma-separated."""
    return typer.Option(flag, help=help, callback=input_paths(flag))


def file_out(flag: str, help: str) -> Any:
    """An output file, refused at once where it cannot be written."""
    return typer.Option(flag, help=help, callback=output_file(flag))


def dir_out(flag: str, help: str) -> Any:
    """An output folder (created when missing), refused at once where it cannot be."""
    return typer.Option(flag, help=help, callback=output_dir(flag))


def machine_name(flag: str, help: str) -> Any:
    """A machine's name, checked by the twin's mapping rule (a topic level and a browse name:
    no MQTT wildcard, no '/', at most 100 characters) while parsing."""

    def callback(value: str | None) -> str | None:
        import re

        from drafttwin.errors import ConfigError
        from drafttwin.twin.sources.mapping import MACHINE_NAME

        if value is None:  # an optional one not given
            return None
        if not re.fullmatch(MACHINE_NAME, value):
            raise ConfigError(f"{value[:100]!r} is not a machine name", where=flag,
                              fix="use letters, digits, '_', '.' and '-' (no MQTT wildcard, "
                              "no '/'), at most 100 characters")  # fmt: skip
        return value

    return typer.Option(flag, help=help, callback=callback)


# -- the drive train, the data and its channels --------------------------------------------

PresetOpt = Annotated[str | None, typer.Option("--preset", help="Built-in drive train (default: fa320a).")]  # fmt: skip
ConfigOpt = Annotated[Path | None, file_in("--config", "Drive-train TOML file (see docs/mechanics.md).")]  # fmt: skip


@dataclass(frozen=True)
class TrainOptions:
    """The drive train: ``--preset`` or ``--config`` (an option group, see cli/_groups.py)."""

    preset: PresetOpt = None
    config: ConfigOpt = None

    def load(self) -> DriveTrain:
        """The drive train they name (the FA320A preset when neither is given)."""
        # the machine's own spelling (FA320A) names the preset too
        return load_train(None if self.preset is None else self.preset.lower(), self.config)


DataOpt = Annotated[str, files_in(
    "--data", "'default' (the embedded FA320A plant data) or CSV/Parquet file(s), comma-separated "
    "(separate experiments: no model window crosses from one to the next).")]  # fmt: skip
TestDataOpt = Annotated[str | None, files_in(
    "--test-data", "Separate test record(s), comma-separated: scored whole instead of the "
    "chronological split.")]  # fmt: skip
OutputsOpt = Annotated[str | None, typer.Option("--outputs", help="Output channels "
                       "NAME[,NAME...] (default: the FA320A rollers front, second, third, back).")]  # fmt: skip
InputsOpt = Annotated[str | None, typer.Option("--inputs", help=(
    "Exogenous input channels NAME[,NAME...] of the data (set-points, a drive voltage): the "
    "networks see them; a model that takes none (the physics alone, persistence) reads them "
    "only. Set-point columns (supply_hz, setpoint_*) are always read for the physics."))]  # fmt: skip
TimeColumnOpt = Annotated[str | None, typer.Option("--time-column", help="Name of the time column: seconds, or the unit its name gives (time_ms, 'time \\[ms]', t_min); the --mechanistic files may name theirs so too.")]  # fmt: skip
UnitsOpt = Annotated[str | None, typer.Option("--units", help="Units NAME=UNIT[,...] (e.g. "
                     "y=m,u=V). The rpm plausibility check runs only on channels in rpm (the "
                     "FA320A rollers by default).")]  # fmt: skip
FullModelOpt = Annotated[bool, typer.Option("--full-model/--reduced-model", help=(
    "Simulate the full drive train instead of the reduced one (couplings above 200 Hz rigid, "
    "belts compliant: on the embedded FA320A data the speeds agree within 0.02 % at 1/80 of the "
    "cost; docs/mechanics.md). Simulator files are used as they are."))]  # fmt: skip
MechanisticOpt = Annotated[str | None, typer.Option("--mechanistic", help=(
    "The physics: 'preset' / 'preset:NAME' (fa320a), 'config:FILE.toml' (your drive train), or "
    "simulator output file(s) FILE[,FILE...] (time + one column per output, one file for all "
    "records or one per record). Default: the model file's."),
    callback=physics_paths("--mechanistic"))]  # fmt: skip
TaskOpt = Annotated[str | None, typer.Option("--task", help="prediction (one step ahead, "
                    "default) or simulation (free run from the inputs and --init-samples measured "
                    "samples).")]  # fmt: skip
ColumnsOpt = Annotated[str | None, typer.Option("--columns", help="Map file columns to channels / time / motor: v1=front,v2=second,...")]  # fmt: skip
UnitCheckOpt = Annotated[bool, typer.Option("--unit-check/--no-unit-check",
                                            help="Run the plausibility checks on the channels in rpm.")]  # fmt: skip
RateToleranceOpt = Annotated[float, number("--rate-tolerance", "Allowed time-step jitter, fraction of a step.")]  # fmt: skip
InitOpt = Annotated[int | None, number("--init-samples", "Simulation: measured samples at the "
                    "start of each record the free run may use (default: the model's window).")]  # fmt: skip

# -- runs: how long, how fast, how many, what is printed -----------------------------------

DurationOpt = Annotated[float, number("--duration", "Recorded machine time, s.")]
StopAfterOpt = Annotated[float | None, number("--duration", "Stop after this many seconds (default: run on).")]  # fmt: skip
SampleRateOpt = Annotated[float, number("--rate", "Sample rate, Hz.")]
EpochsOpt = Annotated[int | None, number("--epochs", "Most training epochs per network (default: "
                      "the profile's); a small number gives a quick first look.")]  # fmt: skip
WorkersOpt = Annotated[int, number("--workers", "Parallel processes.")]
OutDirOpt = Annotated[Path, dir_out("--out", "Output folder.")]
FarPerDayOpt = Annotated[float, number("--far-per-day", "False alarms allowed per 24 h of healthy running.")]  # fmt: skip
LevellerOpt = Annotated[str | None, typer.Option("--leveller", help=(
    "An open-loop autoleveller: INTENSITY[,ACTION_OFFSET_MM] (1,0: full levelling at the true "
    "action point; the offset in mm of fed sliver is a setting's error). Infeed scanning "
    "rollers 600 mm before the back nip, a store clocked by the feeding rollers, the "
    "regulating drive a 5-ms lag (docs/sliver.md)."))]  # fmt: skip
LevellerFaultOpt = Annotated[list[str] | None, typer.Option("--leveller-fault", help=(
    "A fault of the leveller (repeatable): infeed-drift=PCT_PER_MIN (the scanning rollers' "
    "gain drifts) or sluggish-drive=MS (the drive's time constant, nominal 5 ms); a wrong "
    "action point is --leveller's offset."))]  # fmt: skip
JsonOpt = Annotated[bool, typer.Option("--json", help="Print the result as JSON.")]
# derived from the parameter's name, as --quiet/--no-quiet
QuietOpt = Annotated[bool, typer.Option(help="No progress bar.")]
