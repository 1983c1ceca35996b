"""``drafttwin calibrate``: the drive train's uncertain parameters from measured records."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich import box
from rich.markup import escape
from rich.table import Table

from drafttwin.cli._data import ChannelOptions, nominal_rpm
from drafttwin.cli._groups import stops_cleanly, with_group
from drafttwin.cli._options import (
    FullModelOpt,
    JsonOpt,
    TrainOptions,
    file_out,
    files_in,
    number,
)
from drafttwin.cli.typer_app import app, console, err_console, print_json, print_table
from drafttwin.errors import ConfigError, DataError

if TYPE_CHECKING:
    from drafttwin.calibration import Calibration
    from drafttwin.mechanics import DriveTrain


TrainOutOpt = Annotated[Path, file_out(
    "--out", "The calibrated drive train, .toml (usable with --config and --mechanistic "
    "config:FILE); the report goes beside it as NAME.calibration.json (refused where a file not "
    "written by calibrate has that name).")]  # fmt: skip
RecordsOpt = Annotated[str, files_in("--data", "Measured records, comma-separated (steady, "
                       "start-up and speed-change records together identify the most); 'default' "
                       "for the embedded data.")]  # fmt: skip
ParamsOpt = Annotated[str | None, typer.Option("--params", help=(
    "Parameters to estimate, dotted names as in the plant's sidecar "
    "(roller.front.friction_coefficient, belt.main_belt.axial_rigidity_n, "
    "motor.breakdown_torque_ratio, motor.rated_slip, bearing.<node>, ...). Default: all a "
    "drawing does not give."))]  # fmt: skip
BlockOpt = Annotated[float, number("--block", "Block length, s: the fit compares block means.")]
LinesOpt = Annotated[bool, typer.Option("--lines", help=(
    "Also fit the known-frequency terms (once and twice per revolution of every shaft, gear "
    "meshes, chain tooth pass; angles from the measured speeds) to the calibrated physics' "
    "residual, and report the share of its fluctuation they explain on each record's held-out "
    "last 30 % and the largest terms."))]  # fmt: skip
WanderOpt = Annotated[bool | None, typer.Option("--wander/--no-wander", show_default=False, help=(
    "Model the motor channel's error as white noise plus a slow wander (the VFD's supply "
    "frequency, which only the motor sees; size and correlation time by maximum likelihood) and "
    "refit by generalised least squares; standstill and the first 0.5 s after a start are then "
    "not scored. Needs a recorded motor speed. The report's residual_model also says how well "
    "the records pin the steady level (level_sd) and how far a new minute's own wander moves "
    "its mean (mean_sd_60s): the wander's share of the bias on another record. Default: on when "
    "the records have a motor speed, plain least squares otherwise (docs/calibration.md)."))]  # fmt: skip
# derived from the parameter's name, as --quiet/--no-quiet
QuietOpt = Annotated[bool, typer.Option(help="No progress messages.")]


@app.command()
@with_group("channels", ChannelOptions)
@with_group("drive", TrainOptions)
@stops_cleanly("nothing was written")
def calibrate(
    out: TrainOutOpt, data: RecordsOpt, channels: ChannelOptions, drive: TrainOptions,
    params: ParamsOpt = None, block: BlockOpt = 0.1, full_model: FullModelOpt = False,
    lines: LinesOpt = False, wander: WanderOpt = None,
    as_json: JsonOpt = False, quiet: QuietOpt = False,
) -> None:  # fmt: skip
    """Estimate the physical parameters of a drive train from measured speeds, with standard
    errors and an identifiability verdict per parameter, and write the calibrated train.

    Output-error least squares on block means of the records (the simulation follows each
    record's set-points); parameters the data do not see, or cannot separate, are reported so
    and stay nominal; parameters that act only together are fitted as one factor.
    """
    from drafttwin._io import write_texts_atomic
    from drafttwin._json import dumps_strict
    from drafttwin.calibration import calibrate as run
    from drafttwin.calibration.io import train_toml

    if out.suffix.lower() != ".toml":
        raise ConfigError(f"unsupported output file type '{out.suffix or '(none)'}'",
                          source=out, where="--out", fix="name it *.toml")  # fmt: skip
    report_file = report_path(out)
    train = drive.load()
    parsed = replace(channels.parse().for_train(train), nominal_rpm=nominal_rpm(train))
    needs = tuple(c.channel for c in train.spec.input)
    series = parsed.read(data, needs)
    model, name = _model(full_model)
    names = None if params is None else [p.strip() for p in params.split(",") if p.strip()]
    if names == []:
        raise ConfigError("--params names no parameter", where="--params",
                          fix="name parameters (e.g. --params motor.rated_slip), or leave "
                          "--params out to screen them all")  # fmt: skip
    say = None if (quiet or as_json) else (lambda msg: err_console.print(escape(msg)))
    has_motor = series.motor_rpm is not None or "motor" in series.channels
    if wander and not has_motor:
        raise DataError("no recorded motor speed to model the supply's wander on", source=data,
                        where="motor column",
                        fix="record the motor speed (a 'motor' column) or use --no-wander")  # fmt: skip
    if wander is None:  # the wander model needs the motor channel; plain least squares without
        wander = has_motor
        if say:
            say("supply-wander model " + ("on (a motor speed is recorded; --no-wander: plain "
                "least squares)" if wander else "off (no motor speed recorded)"))  # fmt: skip
    result = run(train, series, names, block_s=block, model=model, model_name=name,
                 progress=say, lines=lines,
                 coloured=("motor",) if wander else ())  # fmt: skip
    report = {"report": REPORT_KIND, **result.to_dict(), "data": data,
              "drive_train": train.spec.train.name}  # fmt: skip
    # the train and its report are renamed into place together, or neither is
    write_texts_atomic({
        out: train_toml(result.train, f"calibrated by drafttwin calibrate on {data}"),
        report_file: dumps_strict(report),
    })  # fmt: skip
    if as_json:
        print_json(report)
        return
    _print(result)
    console.print(f"wrote {escape(str(out))} and {escape(str(report_file))}")


REPORT_KIND = "drafttwin calibrate"
"""The report's first field: what marks a file as a report this command may replace."""


def report_path(out: Path) -> Path:
    """Where the report of ``--out NAME.toml`` goes: ``NAME.calibration.json``, a name of its
    own (a plant record ``NAME.csv`` keeps its ``NAME.json`` sidecar). A file of that name
    that an earlier calibrate did not write (a sidecar of a record ``NAME.calibration.csv``,
    the user's own) is refused, never overwritten."""
    import json

    path = out.with_name(f"{out.stem}.calibration.json")
    if not path.exists():
        return path
    try:
        ours = json.loads(path.read_text(encoding="utf-8")).get("report") == REPORT_KIND
    except (OSError, ValueError, AttributeError):
        ours = False
    if not ours:
        raise ConfigError(f"{path.name} exists and is not a report of drafttwin calibrate",
                          source=path, where="--out",
                          fix="choose another --out name, or move that file")  # fmt: skip
    return path


def _model(full: bool) -> tuple[Callable[[DriveTrain], DriveTrain] | None, str]:
    from drafttwin.mechanics import reduce

    return (None, "full") if full else (reduce, "reduced")


def _print(result: Calibration) -> None:
    table = Table(title="calibrated parameters", box=box.SIMPLE_HEAD, pad_edge=False,
                  collapse_padding=True)  # fmt: skip
    for col in ("parameter", "nominal", "estimate", "± SE", "factor", "verdict"):
        # whole names and numbers on one line (names differ at their ends); the verdict wraps
        table.add_column(col, justify="left" if col in ("parameter", "verdict") else "right",
                         no_wrap=True)  # fmt: skip
    aside = ("not from this data", "not separable in this data")  # nominal: listed below
    for e in result.estimates:
        if e.verdict in aside:
            continue
        se = "-" if e.std_error != e.std_error else f"{e.std_error:.4g}"
        table.add_row(escape(e.name), f"{e.nominal:.5g}", f"{e.estimate:.5g}", se,
                      f"{e.factor:.4f}", e.verdict)  # fmt: skip
    # whole names and numbers on one line: a pipe or file has no width to fit (80 would cut them)
    print_table(table)
    for verdict in aside:
        names = [e.name for e in result.estimates if e.verdict == verdict]
        if names:
            console.print(f"{verdict} (left nominal): {escape(', '.join(names))}")
    for note in result.notes:
        console.print(escape(note))
    fit = Table(title=f"fit on {result.block_s:g} s block means, {result.records} record(s)")
    for col in ("channel", "unit", "bias before", "bias after", "RMSE before", "RMSE after"):
        fit.add_column(col, justify="left" if col in ("channel", "unit") else "right")
    for c in result.channels:
        fit.add_row(escape(c), result.units.get(c, ""), f"{result.bias_before[c]:.4g}",
                    f"{result.bias_after[c]:.4g}", f"{result.rmse_before[c]:.4g}",
                    f"{result.rmse_after[c]:.4g}")  # fmt: skip
    console.print(fit)
    if result.lines is not None:
        _print_lines(result.lines)
    console.print(f"collinearity index of the free set {result.collinearity:.3g}; "
                  f"{result.evaluations} simulations ({result.model} model, "
                  f"{result.weighting}), "
                  f"{result.wall_s:.0f} s")  # fmt: skip


def _print_lines(lines: dict[str, Any]) -> None:
    share = Table(title="known-frequency terms: share of the physics residual's fluctuation "
                  "they explain")  # fmt: skip
    for col in ("channel", "fitted part", "held-out 30 %"):
        share.add_column(col, justify="left" if col == "channel" else "right")
    for c, v in lines["share_held_out"].items():
        share.add_row(escape(c), f"{lines['share_fit'][c]:.1%}", f"{v:.1%}")
    console.print(share)
    top = Table(title="largest terms (amplitude per channel)")
    channels = list(lines["share_held_out"])
    for col in ("term", "Hz", *channels):
        top.add_column(escape(col), justify="left" if col == "term" else "right")
    for t in lines["lines"][:5]:
        top.add_row(escape(t["name"]), f"{t['frequency_hz']:.2f}",
                    *(f"{t['amplitude'][c]:.3g}" for c in channels))  # fmt: skip
    console.print(top)
