"""``drafttwin sliver``: the sliver a drawing frame delivers, its evenness and its chimneys."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from drafttwin.cli._common import check_output_suffix
from drafttwin.cli._groups import stops_cleanly, with_group
from drafttwin.cli._options import (
    JsonOpt,
    LevellerFaultOpt,
    LevellerOpt,
    QuietOpt,
    TrainOptions,
    file_out,
    number,
)
from drafttwin.cli._oserrors import input_path
from drafttwin.cli.typer_app import app, console, print_json, progress_bar
from drafttwin.errors import ConfigError, DataError

sliver_app = typer.Typer(
    help="The sliver: drafting simulator, evenness, spectrogram, wavelength table, and the "
    "element behind each chimney (docs/sliver.md).",
    no_args_is_help=True,
)
app.add_typer(sliver_app, name="sliver")

# the options of the sliver commands (sliver_read_cmds.py takes them too)
StapleOpt = Annotated[str | None, typer.Option("--staple", help="Fibres: cotton | polyester | a "
                      "CSV staple diagram (columns length_mm, fraction; give --fineness-dtex). "
                      "Default: cotton; a record read without it takes the fibres its sidecar "
                      "names, else says that it assumed cotton.")]  # fmt: skip
FinenessOpt = Annotated[float | None, number("--fineness-dtex", "Fibre fineness, dtex (default: the preset's).")]  # fmt: skip
FinenessCvOpt = Annotated[float | None, number("--fineness-cv", "Fineness CV as a fraction (default: the preset's).")]  # fmt: skip
GaugesOpt = Annotated[str, typer.Option("--gauges", help="Zone gauges main,middle,break in mm "
                      "(FA320A: assumed 44,40,46).")]  # fmt: skip
FibreScaleReadOpt = Annotated[float | None, number(
    "--fibre-scale", "The record was simulated with this many fibres lumped into one (sliver "
    "simulate --fibre-scale): Martindale's limit and the ideal curve follow it (default: the "
    "record's sidecar, as generate --sliver and plant serve --log write it; else 1).")]  # fmt: skip


@dataclass(frozen=True)
class FibreOptions:
    """The fibres: ``--staple``, ``--fineness-dtex``, ``--fineness-cv`` (an option group)."""

    staple: StapleOpt = None
    fineness_dtex: FinenessOpt = None
    fineness_cv: FinenessCvOpt = None

    def diagram(self) -> Any:
        """The staple diagram they describe (the cotton preset where none is given)."""
        return staple_from(self.staple or "cotton", self.fineness_dtex, self.fineness_cv)

    def given(self) -> Any:
        """The staple diagram they describe, or None where none of them was given (a record
        read with them then takes its own fibres, or says which it assumed)."""
        if self.staple is None and self.fineness_dtex is None and self.fineness_cv is None:
            return None
        return self.diagram()


def staple_from(staple: str, fineness: float | None, fineness_cv: float | None) -> Any:
    from dataclasses import replace

    from drafttwin.sliver import StapleDiagram

    if staple in ("cotton", "polyester"):
        diagram = StapleDiagram.preset(staple)
        return replace(diagram,
                       fineness_dtex=diagram.fineness_dtex if fineness is None else fineness,
                       fineness_cv=diagram.fineness_cv if fineness_cv is None else fineness_cv,
                       _moments={})  # fmt: skip
    path = Path(staple)
    if not path.is_file():
        raise ConfigError(f"'{staple}' is neither a staple preset nor a file", where="--staple",
                          fix="cotton, polyester, or a CSV with length_mm, fraction")  # fmt: skip
    if fineness is None:
        raise ConfigError("a staple diagram file needs the fibres' fineness",
                          source=path, where="--fineness-dtex", fix="e.g. --fineness-dtex 1.6")  # fmt: skip
    return StapleDiagram.from_table(path, fineness, fineness_cv or 0.0)


def zones_from(gauges: str) -> Any:
    from drafttwin.sliver import DraftingZones

    try:
        parts = [float(x) for x in gauges.split(",")]
    except ValueError:
        parts = []
    if len(parts) != 3:
        raise ConfigError(f"'{gauges}' is not three numbers", where="--gauges",
                          fix="main,middle,break in mm, e.g. 44,40,46")  # fmt: skip
    return DraftingZones(*parts)


def evenness_table(ev: Any, title: str) -> Table:
    from drafttwin.sliver.irregularity import CUT_LENGTHS_M

    table = Table(title=title)
    table.add_column("measure")
    table.add_column("value", justify="right")
    table.add_row("count", f"{ev.count_ktex:.4f} ktex")
    table.add_row("CV", f"{ev.cv_pct:.3f} %")
    table.add_row("U", f"{ev.u_pct:.3f} %")
    for k, v in ev.cv_cut_pct.items():
        why = ("grid coarser than the cut" if CUT_LENGTHS_M.get(k, math.inf) < ev.step_m / 2
               else "record too short")  # fmt: skip
        table.add_row(f"CV at {k}", f"{v:.3f} %" if v == v else why)
    if ev.martindale_cv_pct is not None:
        table.add_row("Martindale limit", f"{ev.martindale_cv_pct:.3f} %")
        table.add_row("index of irregularity", f"{ev.index_of_irregularity:.2f}")
    return table


def causes_table(causes: list[Any]) -> Table:
    table = Table(title="chimneys and the elements behind them")
    for col in ("wavelength", "amplitude %", "base %", "first cause", "look-alikes / verdict"):
        table.add_column(col, overflow="fold")
    for c in causes:
        top = c.candidates[0].element if c.candidates and c.candidates[0].plausible else "feed"
        table.add_row(f"{c.wavelength_m * 100:.2f} cm", f"{c.amplitude_pct:.3f}",
                      f"{c.base_pct:.3f}", top, c.verdict)  # fmt: skip
    return table


def read_speed_file(path: Path) -> Any:
    """A roller speed file of ``--speeds``, through the data layer's checks; its errors name
    ``--speeds`` (these commands map no columns: the file must name the rollers)."""
    from drafttwin.data.io import read_measurements

    try:
        return read_measurements(path)
    except DataError as exc:
        logged = _plant_log_speeds(path)  # 'plant serve --log' (its sidecar names it)
        if logged is not None:
            return logged
        fix = exc.fix
        if fix is None or "--columns" in fix:
            fix = ("a speed file is a plant record: a time column and the rollers front, "
                   "second, third, back in rpm (generate writes one)")  # fmt: skip
        raise DataError(exc.problem, source=exc.source or path, where="--speeds",
                        fix=fix) from None  # fmt: skip


def _plant_log_speeds(path: Path) -> Any:
    """The roller speeds of a ``plant serve --log`` file of one machine, on the plant's own
    clock (the one its sliver log's readings carry); ``None`` for a file that is no plant
    log. A log of several machines is refused: which one the sliver is of is not said."""
    from drafttwin.wire.plantlog import plant_log_series

    records = plant_log_series(path, own_clock=True)
    if records is None:
        return None
    if len(records) != 1:
        raise DataError(f"a plant log of {len(records)} machines", source=path, where="--speeds",
                        fix="give one machine's speeds (plant serve --log with one machine)")  # fmt: skip
    return records[0]


def _speeds(speeds: str, truth: bool, duration: float, train: Any, detail: bool,
            quiet: bool) -> Any:  # fmt: skip
    """The rollers' surface speeds from ``--speeds``: the physics, or a speed file (measured,
    predicted, or with ``--truth`` the plant's true speeds), with the physics' content above
    the file's Nyquist frequency unless ``--no-detail``."""
    from drafttwin.sliver.physics import physics_speeds, roller_diameters_mm, with_physics_detail
    from drafttwin.sliver.speeds import ROLLER_ORDER, SurfaceSpeeds

    roller_diameters_mm(train)  # a train without the four rollers: refused before any work
    if truth and speeds == "physics":
        raise ConfigError("--truth takes the plant's true speeds beside a speed file, and "
                          "--speeds is physics", where="--truth",
                          fix="give --speeds FILE (a plant record) with --truth, or leave "
                          "--truth out")  # fmt: skip
    if speeds == "physics":
        with progress_bar("physics at 2 kHz (machine s)", duration, quiet=quiet) as bar:
            task = bar.task_ids[0]
            return physics_speeds(train, duration, progress=lambda s: bar.advance(task, s))
    path = Path(speeds)
    series = read_speed_file(path)
    values = series.values
    if truth:
        from drafttwin.plant.emulator import attach_truth

        series = attach_truth(series, path)
        if series.truth is None:
            raise ConfigError("no plant truth beside this file (its .json sidecar and .truth "
                              "file)", source=path, where="--truth",
                              fix="leave out --truth to use the measured speeds")  # fmt: skip
        values = series.truth
    cols = [series.channels.index(r) for r in ROLLER_ORDER]
    label = f"{path.name} ({'true' if truth else 'measured'} speeds)"
    coarse = SurfaceSpeeds.from_rpm(series.time_s, values[:, cols], roller_diameters_mm(train),
                                    label)  # fmt: skip
    return with_physics_detail(coarse, train) if detail else coarse


SliverOutOpt = Annotated[Path, file_out("--out", "Sliver file (.csv or .parquet): "
                        "delivered_length_m, time, linear_density_ktex.")]  # fmt: skip


def _speeds_file(value: str) -> str:
    """``--speeds FILE`` is an input (the sliver must not be written over it, nor over its
    record's files); ``physics`` is none."""
    if value != "physics":
        input_path("--speeds")(Path(value))
    return value


SpeedsOpt = Annotated[str, typer.Option("--speeds", callback=_speeds_file, help=(
    "physics (the drive train simulated at 2 kHz for --duration), or a speed file: measured "
    "(cleaned of gaps), a model's predictions (drafttwin predict --out), or with --truth the "
    "plant's true speeds."))]  # fmt: skip
# derived from the parameter's name, as --truth/--no-truth
TruthOpt = Annotated[bool, typer.Option(help="Use the plant's true speeds of --speeds FILE.")]
PhysicsTimeOpt = Annotated[float, number("--duration", "Machine time for --speeds physics, s (25 s is about 107 m of sliver).")]  # fmt: skip
ReducedOpt = Annotated[bool, typer.Option("--reduced", help="With --speeds physics: the reduced "
                       "drive train (couplings above 200 Hz rigid, belts compliant: their mesh "
                       "lines are gone); faster.")]  # fmt: skip
# derived from the parameter's name, as --detail/--no-detail
DetailOpt = Annotated[bool, typer.Option(help="Add the physics' content above a speed file's "
                      "Nyquist frequency (mesh and once-per-revolution lines).")]  # fmt: skip
DoublingsOpt = Annotated[int, number("--doublings", "Slivers fed side by side.")]
FeedKtexOpt = Annotated[float, number("--feed-ktex", "Count of each fed sliver, ktex.")]
FeedCvOpt = Annotated[float, number("--feed-cv", "Extra irregularity of each fed sliver above a random one (fraction).")]  # fmt: skip
FeedCorrelationOpt = Annotated[float, number("--feed-correlation", "Its correlation length on the fed sliver, m.")]  # fmt: skip
FeedFaultOpt = Annotated[list[str] | None, typer.Option("--feed-fault", help=(
    "A periodic fault of the fed slivers: wavelength=M:amplitude=A[:slivers=one|all]"
    "[:phase=random|same] (wavelength on the fed sliver, m; repeatable)."))]  # fmt: skip
StepOpt = Annotated[float, number("--step-mm", "Delivered-length grid, mm.")]
FibreScaleOpt = Annotated[float, number(
    "--fibre-scale", "Lump this many fibres into one (faster; the random part's variance grows "
    "by the same factor, and evenness and the ideal curve account for it).")]  # fmt: skip
RealDraftingOpt = Annotated[str | None, typer.Option("--real-drafting", help=(
    "Real drafting: ACCELERATION_MM,COUPLING (e.g. 8,1): floating fibres accelerate early, "
    "dragged by fast ones (a drafting wave). Both must be calibrated against a mill's "
    "spectrograms; default: ideal drafting."))]  # fmt: skip
SeedOpt = Annotated[int, number("--seed", "Seed of the fibres.")]


@sliver_app.command("simulate")
@with_group("drive", TrainOptions)
@with_group("fibre_options", FibreOptions)
@stops_cleanly("nothing was written")
def simulate_cmd(
    *,  # keyword-only: the option groups below have no default
    out: SliverOutOpt,
    speeds: SpeedsOpt = "physics",
    truth: TruthOpt = False,
    duration: PhysicsTimeOpt = 25.0,
    drive: TrainOptions,
    reduced: ReducedOpt = False,
    detail: DetailOpt = True,
    fibre_options: FibreOptions,
    doublings: DoublingsOpt = 6,
    feed_ktex: FeedKtexOpt = 5.5,
    feed_cv: FeedCvOpt = 0.0,
    feed_correlation: FeedCorrelationOpt = 0.05,
    feed_fault: FeedFaultOpt = None,
    gauges: GaugesOpt = "44,40,46",
    step_mm: StepOpt = 1.0,
    fibre_scale: FibreScaleOpt = 1.0,
    real_drafting: RealDraftingOpt = None,
    leveller: LevellerOpt = None,
    leveller_fault: LevellerFaultOpt = None,
    seed: SeedOpt = 0,
    as_json: JsonOpt = False,
    quiet: QuietOpt = False,
) -> None:
    """Draft fed slivers through the drafting zones at the rollers' surface speeds, fibre by
    fibre, and write the delivered sliver's linear density on a delivered-length grid."""
    from drafttwin.sliver import Feed, FeedFault, RealDrafting, draft
    from drafttwin.sliver.irregularity import evenness
    from drafttwin.sliver.spectra import spectrogram

    check_output_suffix(out)
    fibres = fibre_options.diagram()
    faults = tuple(FeedFault.parse(f) for f in feed_fault or [])
    feed = Feed(fibres, doublings, feed_ktex, faults, feed_cv, feed_correlation)
    zones = zones_from(gauges)
    real = None
    if real_drafting is not None:
        try:
            acc, coupling = (float(x) for x in real_drafting.split(","))
        except ValueError:
            raise ConfigError(f"'{real_drafting}' is not ACCELERATION_MM,COUPLING",
                              where="--real-drafting", fix="e.g. 8,1") from None  # fmt: skip
        real = RealDrafting(acc, coupling)
    levelling = leveller_from(leveller, leveller_fault)
    train = drive.load()
    if reduced:
        from drafttwin.mechanics import reduce

        train = reduce(train)
    sp = _speeds(speeds, truth, duration, train, detail, quiet or as_json)
    fed_m = sp.delivered_length_m / sp.drafts()["total"] * (2 if real else 1)
    total = round(fed_m, 1)
    with progress_bar("drafting (fed m)", total, quiet=quiet or as_json) as bar:
        task = bar.task_ids[0]

        def fed(metres: float) -> None:  # the estimate leaves out the sliver in the zones
            bar.update(task, completed=min(total, bar.tasks[0].completed + metres))

        sl = draft(sp, feed, zones, step_mm=step_mm, seed=seed, fibre_scale=fibre_scale,
                   real=real, leveller=levelling, progress=fed)  # fmt: skip
    try:  # judged before it is written: a record too short to judge is no result
        ev = evenness(sl.linear_density_ktex, sl.step_m, fibres, fibre_scale)
        chimneys = spectrogram(sl.linear_density_ktex, sl.step_m, fibres,
                               fibre_scale=fibre_scale).chimneys()  # fmt: skip
    except DataError:
        raise DataError(f"the drafted sliver is {sl.length_m:.3g} m ({sl.linear_density_ktex.size} "
                        "points), too short for its evenness", where="--duration",
                        fix="simulate a longer --duration (or a finer --step-mm)") from None  # fmt: skip
    sl.write(out)
    if as_json:
        print_json({"out": str(out), "evenness": ev.to_dict(), "info": sl.info,
                    "chimneys": chimneys})  # fmt: skip
        return
    console.print(evenness_table(ev, f"{sl.length_m:.1f} m of sliver from {sp.source}; "
                                  f"{sl.info['fibres']:,} fibres drawn"))  # fmt: skip
    console.print(f"count expected from the feed: {feed.total_ktex / sp.drafts()['total']:.4f} "
                  f"ktex (fed {feed.total_ktex:g} ktex / draft {sp.drafts()['total']:.4f}); "
                  f"significant chimneys: {len(chimneys)} (drafttwin sliver diagnose names "
                  "their elements)")  # fmt: skip
    if fibre_scale != 1:  # the file holds the densities only: a reader would take every fibre
        console.print(f"note: the file does not record --fibre-scale {fibre_scale:g}: read it "
                      f"with 'sliver spectrogram --fibre-scale {fibre_scale:g}' (or 'sliver "
                      "diagnose'), or its Martindale limit and index of irregularity are those "
                      "of unlumped fibres", highlight=False)  # fmt: skip
    console.print(f"wrote {out}")


def leveller_from(text: str | None, faults: list[str] | None) -> Any:
    """The autoleveller of ``--leveller`` and ``--leveller-fault``, or None."""
    from drafttwin.sliver.leveller import Autoleveller

    if text is None:
        if faults:
            raise ConfigError("--leveller-fault is a fault of the leveller", where="--leveller-fault",
                              fix="add --leveller INTENSITY[,ACTION_OFFSET_MM]")  # fmt: skip
        return None
    return Autoleveller.parse(text, faults or [])
