"""``drafttwin generate``: run the plant emulator and write measured data."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, cast, get_args

import numpy as np
import typer
from rich.table import Table

from drafttwin._limits import check_rk4_steps, check_samples
from drafttwin.cli._common import check_output_suffix
from drafttwin.cli._groups import with_group
from drafttwin.cli._options import (
    DurationOpt,
    LevellerFaultOpt,
    LevellerOpt,
    QuietOpt,
    SampleRateOpt,
    TrainOptions,
    file_in,
    file_out,
    number,
)
from drafttwin.cli._oserrors import same_file
from drafttwin.cli.typer_app import app, console, err_console, progress_bar
from drafttwin.errors import ConfigError

if TYPE_CHECKING:
    from drafttwin.plant import PlantConfig

RecordOutOpt = Annotated[Path, file_out("--out", "Measured data file, .csv or .parquet.")]
SeedOpt = Annotated[int, number("--seed", "Seed of the recording: same seeds, byte-identical files.")]  # fmt: skip
MachineSeedOpt = Annotated[int | None, number(
    "--machine-seed", "Seed of the machine (its true parameters). Two runs with the same "
    "--machine-seed and different --seed are two records of one machine. Default: the "
    "recording's --seed.")]  # fmt: skip
MachineFileOpt = Annotated[Path | None, file_in("--machine", "Record the machine of an earlier run: the .json sidecar it wrote.")]  # fmt: skip
ScenarioOpt = Annotated[str, typer.Option("--scenario", help="steady | startup | speed-change | stop (see docs/plant.md).")]  # fmt: skip
FaultOpt = Annotated[list[str] | None, typer.Option("--fault", help=(
    "Inject a fault: ELEMENT:KIND:severity=S:onset=T[:ramp=R] (T, R in s; repeatable), e.g. "
    "E-F:wear:severity=60:onset=30 or front:gain:severity=0.01:onset=5. Kinds and severity "
    "units: docs/faults.md; a wrong element or kind lists the valid ones."))]  # fmt: skip
SliverOpt = Annotated[bool, typer.Option("--sliver", help=(
    "Make sliver too: the true rollers draft six cotton card slivers (docs/sliver.md); writes "
    "OUT's .sliver file (delivery sensor, infeed sensor) and .sliver.truth file (the true "
    "sliver, 1 mm grid)."))]  # fmt: skip
FeedFaultOpt = Annotated[list[str] | None, typer.Option("--feed-fault", help=(
    "With --sliver: a periodic fault of the card slivers, "
    "wavelength=M:amplitude=A[:slivers=one|all][:phase=random|same]; one sliver running out, "
    "missing=FROM_M-TO_M; a piecing, piecing=AT_M (fed lengths in m from the record's start; "
    "repeatable)."))]  # fmt: skip
GearRunoutOpt = Annotated[str | None, typer.Option("--gear-runout", help=(
    "Each gear's own radial run-out: 'rayleigh' (the plant's default) draws each gear's own "
    "below ISO 1328's allowable 35 um, Rayleigh's law with 99.73 % within it; 'allowable' "
    "gives every gear the allowable value itself (the worst accepted gear everywhere; the "
    "embedded data set's plant; docs/plant.md). Machine parameters from --machine are kept "
    "as they are."), show_default=False)]  # fmt: skip
StartOpt = Annotated[str | None, typer.Option("--start", help=(
    "How the recorded machine reached its set-point: 'run-up' (the plant's default) from rest "
    "along a 2-s ramp, as a real machine does; 'operating-point' placed at full speed "
    "with every excitation switched on at once (the plant before 2026-12-01, the embedded data "
    "set's; a lightly loaded backlash mesh can then land in a rattle state no run-up reaches; "
    "docs/plant.md)."), show_default=False)]  # fmt: skip
FibreScaleOpt = Annotated[float, number("--fibre-scale", "With --sliver: fibres lumped into one "
                          "(1: every fibre, about 1.3e8 per 100 m).")]  # fmt: skip


def _plant_config(gear_runout: str | None, start: str | None = None) -> PlantConfig:
    """The plant's settings with the gears' run-out law named by --gear-runout and the start
    named by --start (none named: the plant's defaults)."""
    from drafttwin.plant import PlantConfig
    from drafttwin.plant.config import Eccentricity, GearRunoutLaw, PlantStart

    config = PlantConfig()
    if gear_runout is not None:
        law = cast(GearRunoutLaw, _choice(gear_runout, GearRunoutLaw, "a run-out law",
                                          "--gear-runout"))  # fmt: skip
        config = config.model_copy(update={"eccentricity": Eccentricity(gear_runout_law=law)})
    if start is not None:
        config = config.model_copy(
            update={"start": cast(PlantStart, _choice(start, PlantStart, "a start", "--start"))}
        )
    return config


def _choice(value: str, kind: Any, what: str, option: str) -> str:
    names = get_args(kind)
    if value not in names:
        raise ConfigError(f"{value!r} is not {what}", where=option,
                          fix=f"give {' or '.join(sorted(names))}")  # fmt: skip
    return value


@app.command()
@with_group("drive", TrainOptions)
def generate(
    out: RecordOutOpt, drive: TrainOptions,
    duration: DurationOpt = 60.0, rate: SampleRateOpt = 100.0,
    seed: SeedOpt = 0, machine_seed: MachineSeedOpt = None, machine: MachineFileOpt = None,
    scenario: ScenarioOpt = "steady", fault: FaultOpt = None,
    sliver: SliverOpt = False, feed_fault: FeedFaultOpt = None, fibre_scale: FibreScaleOpt = 1.0,
    leveller: LevellerOpt = None, leveller_fault: LevellerFaultOpt = None,
    gear_runout: GearRunoutOpt = None, start: StartOpt = None, quiet: QuietOpt = False,
) -> None:  # fmt: skip
    """Run the plant emulator: measured roller speeds with the machine's real imperfections.

    Writes OUT (time, front, second, third, back in rpm, gaps as empty cells, and the VFD
    set-point supply_hz and the motor speed motor in rpm), OUT's .truth file (true speeds,
    where samples were dropped or spiked) and OUT's .json sidecar (seeds, the machine's true
    parameters, effects); with --sliver the sliver files too.
    """
    from drafttwin.plant import Machine, Plant
    from drafttwin.plant.faults import FaultSpec, check_faults
    from drafttwin.plant.scenarios import get_scenario

    check_output_suffix(out)
    _refuse_foreign_beside(out)
    sidecar = out.with_suffix(".json")
    if machine is not None and same_file(machine, sidecar):
        raise ConfigError("is both --machine and the sidecar of --out: writing the record would "
                          "replace the machine it reads", source=machine, where="--machine",
                          fix="copy the machine's file elsewhere first, or choose another --out")  # fmt: skip
    get_scenario(scenario)
    if machine is not None and machine_seed is not None:
        raise ConfigError("--machine and --machine-seed both name the machine",
                          where="--machine", fix="give one of them")  # fmt: skip
    plant = Plant(drive.load(), config=_plant_config(gear_runout, start))
    faults = check_faults([FaultSpec.parse(f) for f in fault or []], plant.train)
    _check_fault_times(faults, duration)
    settings = _sliver_settings(sliver, feed_fault, fibre_scale, out, leveller, leveller_fault)
    if settings is not None:
        check_sliver_rate(rate)
    # refuse a run that would never end (or write tens of GB) before anything starts
    check_samples(duration, rate, where="--duration, --rate")
    check_rk4_steps(duration, plant.train.spec.solver.dt_s, where="--duration")
    if machine is not None:
        chosen = Machine.load(machine, plant.train)
    else:
        chosen = Machine.draw(
            plant.train, plant.config, seed if machine_seed is None else machine_seed
        )
    from drafttwin.execution.interrupt import stop_on_signals

    # SIGTERM / SIGINT: one line, exit 128 + signal, no file half-written (temporaries removed)
    with stop_on_signals("nothing was written"):
        with progress_bar("plant (machine s)", duration, quiet=quiet) as bar:
            task = bar.task_ids[0]
            rec = plant.run(duration, rate, seed=seed, scenario=scenario, machine=chosen,
                            progress=lambda s: bar.advance(task, s), faults=faults,
                            sliver=settings)  # fmt: skip
        if rec.sliver is not None and settings is not None:
            _feed_events_within(settings.feed.events(), float(rec.sliver.fed_length_m[-1]),
                                duration)  # fmt: skip
        paths = rec.write(out)
    table = Table(title=f"plant, scenario '{scenario}', seed {seed}, machine "
                  f"{chosen.source}: {duration:g} s at {rate:g} Hz")  # fmt: skip
    for col in ("channel", "mean rpm", "true std %", "missing", "spikes", "noise rms rpm"):
        table.add_column(col, justify="right" if col != "channel" else "left")
    for j, name in enumerate(rec.series.channels):
        x, t = rec.series.values[:, j], rec.true_rpm[:, j]
        ok = ~np.isnan(x) & ~rec.outlier[:, j]
        noise = float(np.sqrt(np.mean((x[ok] - t[ok]) ** 2)))
        table.add_row(name, f"{np.nanmean(x):.2f}", f"{t.std() / t.mean() * 100:.4f}",
                      str(int(rec.missing[:, j].sum())), str(int(rec.outlier[:, j].sum())),
                      f"{noise:.3f}")  # fmt: skip
    motor = rec.series.motor_rpm
    if motor is not None:  # the VFD's speed reading (no true speed kept beside it)
        table.add_row("motor", f"{np.nanmean(motor):.2f}", "", str(int(np.isnan(motor).sum())),
                      "", "")  # fmt: skip
    console.print(table)
    for label in rec.info["faults"]:
        console.print(f"fault {label['element']}:{label['kind']} severity {label['severity']:g} "
                      f"({label['parameter']}) from {label['onset_s']:g} s, "
                      f"{'ramp ' + format(label['ramp_s'], 'g') + ' s' if label['ramp_s'] else 'abrupt'}")  # fmt: skip
    if rec.sliver is not None:
        summary = rec.sliver.summary
        console.print(f"sliver: {summary['delivered_m']:.1f} m, count "
                      f"{summary['true_count_ktex']:.4f} ktex, CV {summary['true_cv_pct']:.3f} % "
                      f"(Martindale {summary['martindale_cv_pct']:.3f} %), "
                      f"{summary['fibres']:,} fibres")  # fmt: skip
        lev = summary.get("leveller")
        if lev:
            console.print(f"leveller: intensity {lev['intensity']:g}, action point "
                          f"{lev['action_point_mm']:.1f} mm (true {lev['true_action_point_mm']:.1f} "
                          f"mm), drive {1000 * lev['drive']['time_constant_s']:g} ms, infeed drift "
                          f"{lev['infeed_sensor']['drift_pct_per_min']:g} %/min")  # fmt: skip
    console.print("wrote " + ", ".join(str(p) for p in paths))


def _refuse_foreign_beside(out: Path) -> None:
    """Refuse a truth file or sidecar beside --out that an earlier plant record of this name
    did not write (a user's own OUT.json is not the plant's to overwrite)."""
    import json

    sidecar = out.with_suffix(".json")
    truth = out.with_name(f"{out.stem}.truth{out.suffix}")
    files: dict[str, Any] = {}
    if sidecar.exists():
        try:
            found = json.loads(sidecar.read_text(encoding="utf-8")).get("files")
        except (OSError, ValueError, AttributeError):
            found = None
        files = found if isinstance(found, dict) else {}
    ours = files.get("measured") == out.name
    for p in (sidecar, truth):
        if p.exists() and not (ours and (p == sidecar or files.get("truth") == p.name)):
            raise ConfigError(f"{p.name} exists and is not a file of an earlier plant record "
                              f"{out.name}", source=p, where="--out",
                              fix="choose another --out, or move that file")  # fmt: skip


def check_sliver_rate(rate_hz: float) -> None:
    """Refuse a recording rate the sliver cannot be made at: the roller surfaces are simulated
    at 2 kHz on the recording's own kernel blocks (bit for bit the same record), so the rate
    must divide 2 kHz and fill each block of ``BLOCK_S`` with whole samples (checked after
    the whole simulation otherwise, with the plant's internal words)."""
    from drafttwin.mechanics.simulation import BLOCK_S
    from drafttwin.plant.sliver_channel import SURFACE_RATE_HZ

    def carries(rate: float) -> bool:
        return (SURFACE_RATE_HZ / rate).is_integer() and (rate * BLOCK_S).is_integer()

    if carries(rate_hz):
        return
    good = [r for r in (100, 200, 400, 500, 1000, 2000) if carries(r)]
    raise ConfigError(f"{rate_hz:g} Hz cannot carry the sliver: its roller surfaces are "
                      f"simulated at {SURFACE_RATE_HZ:g} Hz on the recording's blocks of "
                      f"{BLOCK_S:g} s, so the rate must divide {SURFACE_RATE_HZ:g} Hz in whole "
                      "samples per block", where="--rate",
                      fix="give --rate " + ", ".join(f"{r:g}" for r in good))  # fmt: skip


def _check_fault_times(faults: tuple[Any, ...], duration_s: float) -> None:
    """A fault that starts after the record's end would be labelled in the sidecar but
    absent from the record: refused. A ramp that outlasts the record is a fault still
    growing at its end: said."""
    for f in faults:
        name = f"{f.element}:{f.kind}"
        if f.onset_s >= duration_s:
            raise ConfigError(f"{name} starts at {f.onset_s:g} s, not before the record's end "
                              f"({duration_s:g} s): the record would hold no fault",
                              where="--fault", fix=f"give onset= below {duration_s:g}, or a "
                              "longer --duration")  # fmt: skip
        if f.ramp_s and f.onset_s + f.ramp_s > duration_s:
            reached = (duration_s - f.onset_s) / f.ramp_s
            err_console.print(f"note: {name}'s ramp ends at {f.onset_s + f.ramp_s:g} s, after the "
                              f"record ({duration_s:g} s): it reaches {reached:.0%} of severity "
                              f"{f.severity:g}", highlight=False, soft_wrap=True)  # fmt: skip


def _sliver_settings(sliver: bool, feed_fault: list[str] | None, fibre_scale: float,
                     out: Path, leveller: str | None = None,
                     leveller_fault: list[str] | None = None) -> Any:  # fmt: skip
    """The plant's sliver settings, or None; refuses sliver files beside --out that an
    earlier plant record of this name did not write (they are not the user's to lose)."""
    settings = sliver_settings(sliver, feed_fault, fibre_scale, leveller, leveller_fault)
    if settings is None:
        return None
    from drafttwin.plant.sliver_channel import sliver_paths
    from drafttwin.sliver.record import sliver_beside

    ours = sliver_beside(out)
    for p in sliver_paths(out):
        if p.exists() and (ours is None or p.name not in (ours.sliver.name,
                                                          f"{out.stem}.sliver.truth{out.suffix}")):  # fmt: skip
            raise ConfigError(f"{p.name} exists and is not the sliver of an earlier plant "
                              "record of this name", source=p, where="--out",
                              fix="choose another --out or move the file")  # fmt: skip
    return settings


def _feed_events_within(events: list[dict[str, Any]], fed_m: float, duration_s: float) -> None:
    """Refuse a feed event (a sliver running out, a piecing) that begins beyond the sliver
    the record feeds: it would not happen, while the sidecar listed it (a 60-s record feeds
    about 39 m; ``missing=60-120`` made a healthy record labelled faulty)."""
    for ev in events:
        start = float(ev["from_m"] if ev["kind"] == "missing" else ev["at_m"])
        if start >= fed_m:
            text = (f"missing={ev['from_m']:g}-{ev['to_m']:g}" if ev["kind"] == "missing"
                    else f"piecing={ev['at_m']:g}")  # fmt: skip
            per_s = fed_m / duration_s if duration_s > 0 else math.nan
            raise ConfigError(f"{text} begins at {start:g} m of fed sliver, and this record "
                              f"feeds {fed_m:.1f} m ({per_s:.2f} m a second): it would not "
                              "happen", where="--feed-fault",
                              fix=f"give --duration {math.ceil(1.2 * start / per_s):d} or more, "
                              f"or place it within the first {fed_m:.0f} m (fed length, not "
                              "delivered)")  # fmt: skip


def sliver_settings(sliver: bool, feed_fault: list[str] | None, fibre_scale: float,
                    leveller: str | None, leveller_fault: list[str] | None) -> Any:  # fmt: skip
    """The plant's sliver settings of ``--feed-fault``, ``--fibre-scale``, ``--leveller`` and
    ``--leveller-fault`` (``generate --sliver`` and ``plant serve --sliver``); ``None``
    without ``--sliver``, where those options are refused."""
    if not sliver:
        if feed_fault or fibre_scale != 1.0 or leveller or leveller_fault:
            raise ConfigError("--feed-fault, --fibre-scale and --leveller shape the sliver",
                              where="--feed-fault" if feed_fault else "--leveller"
                              if leveller or leveller_fault else "--fibre-scale",
                              fix="add --sliver")  # fmt: skip
        return None
    from dataclasses import replace

    from drafttwin.cli.sliver_cmds import leveller_from
    from drafttwin.plant.sliver_channel import SliverSettings, default_feed
    from drafttwin.sliver import FeedFault
    from drafttwin.sliver.feed import parse_feed_event

    periodic, missing, piecings = [], None, []
    for text in feed_fault or []:
        event = parse_feed_event(text)
        if event is None:
            periodic.append(FeedFault.parse(text))
        elif event[0] == "missing":
            if missing is not None:
                raise ConfigError("two missing= feed faults", where="--feed-fault",
                                  fix="one sliver runs out once per record")  # fmt: skip
            missing = (event[1][0], event[1][1])
        else:
            piecings.append(event[1][0])
    feed = replace(default_feed(tuple(periodic)), runs_out_m=missing, piecings_m=tuple(piecings))
    levelling = leveller_from(leveller, leveller_fault)
    settings = replace(SliverSettings(), feed=feed, fibre_scale=fibre_scale, leveller=levelling)
    if levelling is not None:
        settings = replace(settings, infeed=levelling.sensor)
    return settings
