"""``drafttwin sliver``: the sliver a drawing frame delivers, its evenness and its chimneys."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from drafttwin.cli._bounds import bounded
from drafttwin.cli._common import check_output_suffix, load_train
from drafttwin.cli._oserrors import input_path, output_file
from drafttwin.cli.app import app, console, print_json, progress_bar
from drafttwin.cli.mechanics_cmds import ConfigOpt, PresetOpt
from drafttwin.errors import ConfigError

sliver_app = typer.Typer(
    help="The sliver: drafting simulator, evenness, spectrogram, wavelength table, and the "
    "element behind each chimney (docs/sliver.md).",
    no_args_is_help=True,
)
app.add_typer(sliver_app, name="sliver")

StapleOpt = Annotated[
    str, typer.Option(help="Fibres: cotton | polyester | a CSV staple diagram (columns "
                      "length_mm, fraction; give --fineness-dtex).")]  # fmt: skip
FinenessOpt = Annotated[
    float | None, typer.Option(help="Fibre fineness, dtex (default: the preset's).",
                               callback=bounded("--fineness-dtex"))]  # fmt: skip
FinenessCvOpt = Annotated[
    float | None, typer.Option(help="Fineness CV as a fraction (default: the preset's).",
                               callback=bounded("--fineness-cv"))]  # fmt: skip
GaugesOpt = Annotated[
    str, typer.Option(help="Zone gauges main,middle,break in mm (FA320A: assumed 44,40,46).")
]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print one JSON object.")]
FibreScaleReadOpt = Annotated[float, typer.Option(
    help="The record was simulated with this many fibres lumped into one (sliver simulate "
    "--fibre-scale): Martindale's limit and the ideal curve follow it.",
    callback=bounded("--fibre-scale"))]  # fmt: skip


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


def _evenness_table(ev: Any, title: str) -> Table:
    table = Table(title=title)
    table.add_column("measure")
    table.add_column("value", justify="right")
    table.add_row("count", f"{ev.count_ktex:.4f} ktex")
    table.add_row("CV", f"{ev.cv_pct:.3f} %")
    table.add_row("U", f"{ev.u_pct:.3f} %")
    for k, v in ev.cv_cut_pct.items():
        table.add_row(f"CV at {k}", f"{v:.3f} %" if v == v else "record too short")
    if ev.martindale_cv_pct is not None:
        table.add_row("Martindale limit", f"{ev.martindale_cv_pct:.3f} %")
        table.add_row("index of irregularity", f"{ev.index_of_irregularity:.2f}")
    return table


def _causes_table(causes: list[Any]) -> Table:
    table = Table(title="chimneys and the elements behind them")
    for col in ("wavelength", "amplitude %", "base %", "first cause", "look-alikes / verdict"):
        table.add_column(col, overflow="fold")
    for c in causes:
        top = c.candidates[0].element if c.candidates and c.candidates[0].plausible else "feed"
        table.add_row(f"{c.wavelength_m * 100:.2f} cm", f"{c.amplitude_pct:.3f}",
                      f"{c.base_pct:.3f}", top, c.verdict)  # fmt: skip
    return table


def _speeds(speeds: str, truth: bool, duration: float, train: Any, detail: bool,
            quiet: bool) -> Any:  # fmt: skip
    """The rollers' surface speeds from ``--speeds``: the physics, or a speed file (measured,
    predicted, or with ``--truth`` the plant's true speeds), with the physics' content above
    the file's Nyquist frequency unless ``--no-detail``."""
    from drafttwin.sliver.physics import physics_speeds, roller_diameters_mm, with_physics_detail
    from drafttwin.sliver.speeds import ROLLER_ORDER, SurfaceSpeeds

    roller_diameters_mm(train)  # a train without the four rollers: refused before any work
    if speeds == "physics":
        with progress_bar("physics at 2 kHz (machine s)", duration, quiet=quiet) as bar:
            task = bar.task_ids[0]
            return physics_speeds(train, duration, progress=lambda s: bar.advance(task, s))
    from drafttwin.data.io import read_measurements

    path = Path(speeds)
    series = read_measurements(path)
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


@sliver_app.command("simulate")
def simulate_cmd(
    out: Annotated[
        Path,
        typer.Option(
            help="Sliver file (.csv or .parquet): delivered_length_m, time, linear_density_ktex.",
            callback=output_file("--out"),
        ),
    ],  # fmt: skip
    speeds: Annotated[
        str,
        typer.Option(
            help="physics (the drive train simulated at 2 kHz for --duration), or a speed file: "
            "measured (cleaned of gaps), a model's predictions (drafttwin predict --out), or with "
            "--truth the plant's true speeds."
        ),
    ] = "physics",  # fmt: skip
    truth: Annotated[
        bool, typer.Option(help="Use the plant's true speeds of --speeds FILE.")
    ] = False,
    duration: Annotated[
        float,
        typer.Option(
            help="Machine time for --speeds physics, s (25 s is about 107 m of sliver).",
            callback=bounded("--duration"),
        ),
    ] = 25.0,  # fmt: skip
    preset: PresetOpt = None,
    config: ConfigOpt = None,
    detail: Annotated[
        bool,
        typer.Option(
            help="Add the physics' content above a speed file's "
            "Nyquist frequency (mesh and once-per-revolution "
            "lines)."
        ),
    ] = True,  # fmt: skip
    staple: StapleOpt = "cotton",
    fineness_dtex: FinenessOpt = None,
    fineness_cv: FinenessCvOpt = None,
    doublings: Annotated[
        int, typer.Option(help="Slivers fed side by side.", callback=bounded("--doublings"))
    ] = 6,  # fmt: skip
    feed_ktex: Annotated[
        float, typer.Option(help="Count of each fed sliver, ktex.", callback=bounded("--feed-ktex"))
    ] = 5.5,  # fmt: skip
    feed_cv: Annotated[
        float,
        typer.Option(
            help="Extra irregularity of each fed sliver above a random one (fraction).",
            callback=bounded("--feed-cv"),
        ),
    ] = 0.0,  # fmt: skip
    feed_correlation: Annotated[
        float,
        typer.Option(
            help="Its correlation length on the fed sliver, m.",
            callback=bounded("--feed-correlation"),
        ),
    ] = 0.05,  # fmt: skip
    feed_fault: Annotated[
        list[str] | None,
        typer.Option(
            "--feed-fault",
            help="A periodic fault of the fed slivers: wavelength=M:amplitude=A"
            "[:slivers=one|all][:phase=random|same] (wavelength on the fed sliver, m; repeatable).",
        ),
    ] = None,  # fmt: skip
    gauges: GaugesOpt = "44,40,46",
    step_mm: Annotated[
        float, typer.Option(help="Delivered-length grid, mm.", callback=bounded("--step-mm"))
    ] = 1.0,  # fmt: skip
    fibre_scale: Annotated[
        float,
        typer.Option(
            help="Lump this many fibres into one (faster; the random part's variance grows by the "
            "same factor, and evenness and the ideal curve account for it).",
            callback=bounded("--fibre-scale"),
        ),
    ] = 1.0,  # fmt: skip
    real_drafting: Annotated[
        str | None,
        typer.Option(
            help="Real drafting: ACCELERATION_MM,COUPLING (e.g. 8,1): floating fibres accelerate "
            "early, dragged by fast ones (a drafting wave). Both must be calibrated against a "
            "mill's spectrograms; default: ideal drafting."
        ),
    ] = None,  # fmt: skip
    leveller: Annotated[
        str | None,
        typer.Option(
            help="An open-loop autoleveller: INTENSITY[,ACTION_OFFSET_MM] (1,0: full levelling at "
            "the true action point; the offset in mm of fed sliver is a setting's error)."
        ),
    ] = None,  # fmt: skip
    seed: Annotated[int, typer.Option(help="Seed of the fibres.", callback=bounded("--seed"))] = 0,
    as_json: JsonOpt = False,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
) -> None:
    """Draft fed slivers through the drafting zones at the rollers' surface speeds, fibre by
    fibre, and write the delivered sliver's linear density on a delivered-length grid."""
    from drafttwin.sliver import Feed, FeedFault, RealDrafting, draft
    from drafttwin.sliver.evenness import evenness
    from drafttwin.sliver.spectrogram import spectrogram

    check_output_suffix(out)
    fibres = staple_from(staple, fineness_dtex, fineness_cv)
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
    levelling = _leveller(leveller)
    train = load_train(preset, config)
    sp = _speeds(speeds, truth, duration, train, detail, quiet or as_json)
    fed_m = sp.delivered_length_m / sp.drafts()["total"] * (2 if real else 1)
    with progress_bar("drafting (fed m)", round(fed_m, 1), quiet=quiet or as_json) as bar:
        task = bar.task_ids[0]
        sl = draft(sp, feed, zones, step_mm=step_mm, seed=seed, fibre_scale=fibre_scale,
                   real=real, leveller=levelling,
                   progress=lambda m: bar.advance(task, m))  # fmt: skip
    sl.write(out)
    ev = evenness(sl.linear_density_ktex, sl.step_m, fibres, fibre_scale)
    chimneys = spectrogram(sl.linear_density_ktex, sl.step_m, fibres,
                           fibre_scale=fibre_scale).chimneys()  # fmt: skip
    if as_json:
        print_json({"out": str(out), "evenness": ev.to_dict(), "info": sl.info,
                    "chimneys": chimneys})  # fmt: skip
        return
    console.print(_evenness_table(ev, f"{sl.length_m:.1f} m of sliver from {sp.source}; "
                                  f"{sl.info['fibres']:,} fibres drawn"))  # fmt: skip
    console.print(f"count expected from the feed: {feed.total_ktex / sp.drafts()['total']:.4f} "
                  f"ktex (fed {feed.total_ktex:g} ktex / draft {sp.drafts()['total']:.4f}); "
                  f"significant chimneys: {len(chimneys)} (drafttwin sliver diagnose names "
                  "their elements)")  # fmt: skip
    console.print(f"wrote {out}")


def _leveller(text: str | None) -> Any:
    from drafttwin.sliver.leveller import Autoleveller

    if text is None:
        return None
    try:
        parts = [float(x) for x in text.split(",")]
    except ValueError:
        parts = []
    if len(parts) not in (1, 2):
        raise ConfigError(f"'{text}' is not INTENSITY[,ACTION_OFFSET_MM]", where="--leveller",
                          fix="e.g. 1 or 1,15")  # fmt: skip
    return Autoleveller(parts[0], parts[1] if len(parts) == 2 else 0.0)


@sliver_app.command("spectrogram")
def spectrogram_cmd(
    data: Annotated[
        Path,
        typer.Option(
            help="Sliver record: delivered_length_m and a density "
            "column (drafttwin sliver simulate, generate --sliver).",
            dir_okay=False,
            readable=False,
            callback=input_path("--data"),
        ),
    ],  # fmt: skip
    column: Annotated[str, typer.Option(help="Density column.")] = "linear_density_ktex",
    staple: StapleOpt = "cotton",
    fineness_dtex: FinenessOpt = None,
    fineness_cv: FinenessCvOpt = None,
    sensor_mm: Annotated[
        float,
        typer.Option(
            help="Averaging length of the sensor that read the record, mm (for the ideal curve).",
            callback=bounded("--sensor-mm"),
        ),
    ] = 0.0,  # fmt: skip
    fibre_scale: FibreScaleReadOpt = 1.0,
    out: Annotated[
        Path | None,
        typer.Option(help="The channel table (.csv or .parquet).", callback=output_file("--out")),
    ] = None,  # fmt: skip
    as_json: JsonOpt = False,
) -> None:
    """Count, CV %, U %, CV at cut lengths and the spectrogram as evenness testers draw it
    (10 channels per octave, ideal curve of a random sliver of the same fibres, significant
    channels, chimneys)."""
    from drafttwin.cli._common import write_frame
    from drafttwin.sliver import read_sliver
    from drafttwin.sliver.evenness import evenness
    from drafttwin.sliver.spectrogram import spectrogram

    if out is not None:
        check_output_suffix(out)
    fibres = staple_from(staple, fineness_dtex, fineness_cv)
    sl = read_sliver(data, column, staple=fibres)
    ev = evenness(sl.linear_density_ktex, sl.step_m, fibres, fibre_scale)
    spec = spectrogram(sl.linear_density_ktex, sl.step_m, fibres, fibre_scale=fibre_scale,
                       sensor_length_m=sensor_mm * 1e-3)  # fmt: skip
    frame = spec.to_frame()
    if out is not None:
        write_frame(frame, out)
    if as_json:
        print_json({"evenness": ev.to_dict(), "spectrogram": frame.to_dict(orient="list")})
        return
    console.print(_evenness_table(ev, f"{data.name}: {sl.length_m:.1f} m"))
    table = Table(title="spectrogram (significant channels; * chimney)")
    for col in ("wavelength", "amplitude %", "ideal %", "base %", ""):
        table.add_column(col, justify="right")
    for _, r in frame[frame["significant"]].iterrows():
        ideal = "" if r["ideal_pct"] != r["ideal_pct"] else f"{r['ideal_pct']:.3f}"
        table.add_row(f"{r['wavelength_m'] * 100:.2f} cm", f"{r['amplitude_pct']:.3f}", ideal,
                      f"{r['base_pct']:.3f}", "*" if r["chimney"] else "")  # fmt: skip
    console.print(table)
    if out is not None:
        console.print(f"wrote {out}")


@sliver_app.command("wavelengths")
def wavelengths_cmd(
    preset: PresetOpt = None,
    config: ConfigOpt = None,
    motor_rpm: Annotated[
        float | None,
        typer.Option(
            help="Motor speed, rpm (default: the running point by torque balance).",
            callback=bounded("--motor-rpm"),
        ),
    ] = None,  # fmt: skip
    harmonics: Annotated[
        int, typer.Option(help="Harmonics listed per element.", callback=bounded("--harmonics"))
    ] = 3,  # fmt: skip
    out: Annotated[
        Path | None,
        typer.Option(help="The table (.csv or .parquet).", callback=output_file("--out")),
    ] = None,  # fmt: skip
    as_json: JsonOpt = False,
) -> None:
    """Every rotating element of the drive train (motor, shafts, pulleys, belt pass,
    sprockets, chain pass and teeth, each gear and mesh, each roller) with its frequency and
    its wavelength on the delivered sliver, and the rollers it moves."""
    from drafttwin.cli._common import write_frame
    from drafttwin.sliver import wavelength_table

    if out is not None:
        check_output_suffix(out)
    table = wavelength_table(load_train(preset, config), motor_rpm=motor_rpm, harmonics=harmonics)
    if out is not None:
        write_frame(table.to_frame(), out)
    if as_json:
        print_json(table.to_dict())
        return
    shown = Table(title=f"{table.train}: delivery {table.delivery_m_min:.2f} m/min, motor "
                  f"{table.motor_rpm:.1f} rpm")  # fmt: skip
    for col in ("element", "kind", "Hz", "wavelength", "harmonics", "moves"):
        shown.add_column(col, justify="right" if col in ("Hz", "wavelength") else "left",
                         overflow="fold")  # fmt: skip
    for e in table.elements:
        harm = ", ".join(_cm(w) for w in e.harmonics_m(harmonics)[1:])
        shown.add_row(e.name, e.kind, f"{e.frequency_hz:.3f}", _cm(e.wavelength_m), harm,
                      ",".join(e.rollers))  # fmt: skip
    console.print(shown)
    if out is not None:
        console.print(f"wrote {out}")


def _cm(x: float) -> str:
    return f"{x * 100:.2f} cm" if x < 1 else f"{x:.3f} m"


@sliver_app.command("diagnose")
def diagnose_cmd(
    data: Annotated[
        Path | None,
        typer.Option(
            help="A sliver record, or a speed record with a sliver channel beside it (generate "
            "--sliver): its speeds then count as --speeds.",
            dir_okay=False,
            readable=False,
            callback=input_path("--data"),
        ),
    ] = None,  # fmt: skip
    spectrogram_file: Annotated[
        Path | None,
        typer.Option(
            "--spectrogram",
            help="An evenness tester's spectrogram table instead: wavelength_m | "
            "wavelength_cm | wavelength_mm and amplitude_pct (optional significant).",
            dir_okay=False,
            readable=False,
            callback=input_path("--spectrogram"),
        ),
    ] = None,  # fmt: skip
    speeds: Annotated[
        Path | None,
        typer.Option(
            help="The roller speeds recorded with the sliver (same clock): the encoders' word on "
            "each look-alike.",
            dir_okay=False,
            readable=False,
            callback=input_path("--speeds"),
        ),
    ] = None,  # fmt: skip
    reference: Annotated[
        Path | None,
        typer.Option(
            help="A healthy sliver record of the same machine (or a speed record with one beside "
            "it): chimneys no higher than 1.5 x its channel are the machine's own lines, named "
            "but not counted as new.",
            dir_okay=False,
            readable=False,
            callback=input_path("--reference"),
        ),
    ] = None,  # fmt: skip
    column: Annotated[str, typer.Option(help="Density column of --data.")] = "linear_density_ktex",
    preset: PresetOpt = None,
    config: ConfigOpt = None,
    staple: StapleOpt = "cotton",
    fineness_dtex: FinenessOpt = None,
    fineness_cv: FinenessCvOpt = None,
    gauges: GaugesOpt = "44,40,46",
    sensor_mm: Annotated[
        float | None,
        typer.Option(
            help="Averaging length of the sensor that read --data, mm (default: the plant's "
            "sidecar, else 0).",
            callback=bounded("--sensor-mm"),
        ),
    ] = None,  # fmt: skip
    harmonics: Annotated[
        int, typer.Option(help="Harmonics matched per element.", callback=bounded("--harmonics"))
    ] = 8,  # fmt: skip
    fibre_scale: FibreScaleReadOpt = 1.0,
    report: Annotated[
        Path | None,
        typer.Option(
            help="An HTML page for the quality engineer.", callback=output_file("--report")
        ),
    ] = None,  # fmt: skip
    as_json: JsonOpt = False,
) -> None:
    """Name the drive element behind each chimney of a sliver record or a tester's
    spectrogram: wavelength match with the machine's kinematics, harmonics, the drafting
    transfer (what speed modulation each element would need), look-alikes that share a
    wavelength, feed faults; with --speeds, the roller encoders' share of each chimney."""
    from dataclasses import replace

    from drafttwin.sliver import read_sliver
    from drafttwin.sliver.diagnose import diagnose_sliver
    from drafttwin.sliver.record import sliver_beside
    from drafttwin.sliver.spectrogram import read_tester_spectrogram

    if (data is None) == (spectrogram_file is None):
        raise ConfigError("give one of --data and --spectrogram", where="--data",
                          fix="a sliver record (--data) or a tester's table (--spectrogram)")  # fmt: skip
    if report is not None and report.suffix.lower() not in (".html", ".htm"):
        raise ConfigError(f"'{report.name}' is not an .html file", where="--report",
                          fix="name the page *.html")  # fmt: skip
    fibres = staple_from(staple, fineness_dtex, fineness_cv)
    zones = zones_from(gauges)
    train = load_train(preset, config)
    record: Any
    if data is not None:
        beside = sliver_beside(data)
        if beside is not None:
            speeds = speeds if speeds is not None else beside.speeds
            sensor_mm = beside.sensor_mm if sensor_mm is None else sensor_mm
        record = read_sliver(beside.sliver if beside else data, column, staple=fibres)
        record = replace(record, fibre_scale=fibre_scale)
    else:
        assert spectrogram_file is not None
        record = read_tester_spectrogram(spectrogram_file, staple=fibres)
    ref = None
    if reference is not None:
        ref_beside = sliver_beside(reference)
        ref = read_sliver(ref_beside.sliver if ref_beside else reference, column,
                          option="--reference", staple=fibres)  # fmt: skip
    dx = diagnose_sliver(record, train, fibres, zones, harmonics=harmonics,
                         sensor_length_m=(sensor_mm or 0.0) * 1e-3, reference=ref)  # fmt: skip
    if speeds is not None and data is not None:
        dx = _with_speeds(dx, record, speeds, fibres, zones)
    if report is not None:
        from drafttwin._io import atomic_path
        from drafttwin.report.sliver import sliver_page

        with atomic_path(report) as tmp:
            tmp.write_text(sliver_page(dx, title="What the sliver says",
                                       source=str(data or spectrogram_file)), encoding="utf-8")  # fmt: skip
    if as_json:
        print_json(dx.to_dict())
        return
    if dx.evenness is not None:
        console.print(_evenness_table(dx.evenness, f"{Path(str(data)).name}"))
    if not dx.causes:
        console.print("no significant chimney" + (" beyond the reference" if ref else ""))
    else:
        console.print(_causes_table(dx.causes))
    for c in dx.known:
        console.print(f"the machine's own line (in --reference): {c.wavelength_m * 100:.2f} cm, "
                      f"{c.amplitude_pct:.3f} %: {c.verdict}")  # fmt: skip
    if report is not None:
        console.print(f"wrote {report}")


def _with_speeds(dx: Any, record: Any, speeds: Path, fibres: Any, zones: Any) -> Any:
    from drafttwin.data.io import read_measurements
    from drafttwin.sliver.diagnose import with_encoders

    series = read_measurements(speeds)
    rpm = {r: series.values[:, series.channels.index(r)] for r in series.channels}
    return with_encoders(dx, record, series.time_s, rpm, fibres, zones)
