"""``drafttwin generate-faults``: seeded healthy and faulty plant records with labels."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Any, NamedTuple

import typer
from rich.table import Table

from drafttwin._limits import check_rk4_steps, check_samples
from drafttwin.cli._dxprint import assumed_half_note, inside_alarms, print_diagnosis, print_sliver
from drafttwin.cli._groups import stops_cleanly, with_group
from drafttwin.cli._healthy import head_rows, healthy_records
from drafttwin.cli._options import (
    ColumnsOpt,
    FarPerDayOpt,
    JsonOpt,
    OutDirOpt,
    QuietOpt,
    SampleRateOpt,
    TrainOptions,
    UnitCheckOpt,
    WorkersOpt,
    dir_out,
    file_out,
    files_in,
    number,
)
from drafttwin.cli._oserrors import physics_paths
from drafttwin.cli.benchmark_cmds import benchmark_app
from drafttwin.cli.typer_app import app, console, err_console, progress_bar
from drafttwin.errors import ConfigError, DrafttwinError

CasesOutOpt = Annotated[Path, dir_out("--out", "Folder for the records and cases.json.")]
CasesOpt = Annotated[int, number("--cases", "Number of records (one in 4 healthy).")]
SetSeedOpt = Annotated[int, number("--seed", "Seed of the whole set: same seed, same files.")]
RecordDurationOpt = Annotated[float, number("--duration", "Machine time per record, s.")]


@app.command("generate-faults")
@with_group("drive", TrainOptions)
@stops_cleanly(
    "the records written so far are whole; cases.json lists a set once it is complete: run the command again"
)
def generate_faults(
    *,  # keyword-only: the option group below has no default
    out: CasesOutOpt,
    cases: CasesOpt = 12,
    seed: SetSeedOpt = 0,
    duration: RecordDurationOpt = 60.0,
    rate: SampleRateOpt = 100.0,
    drive: TrainOptions,
    quiet: QuietOpt = False,
) -> None:
    """Write a seeded set of plant records: healthy ones and ones with one fault each.

    Each case draws its own machine and recording seeds, a fault (every element and kind of
    the train, including sensor faults) at a light, moderate or severe level, abrupt or as a
    ramp over 30 % of the record, starting 30-50 % into it. Writes OUT/case_NNNN.parquet with
    its .truth file and .json sidecar (labels under "faults") and OUT/cases.json listing all.
    """
    from drafttwin._io import atomic_path
    from drafttwin._json import dumps_strict
    from drafttwin.plant import Plant
    from drafttwin.plant.fault_cases import draw_cases, run_case

    plant = Plant(drive.load())
    check_samples(duration, rate, where="--duration, --rate")
    check_rk4_steps(duration * cases, plant.train.spec.solver.dt_s, where="--duration, --cases")
    drawn = draw_cases(plant.train, cases, seed, duration)
    table = Table(title=f"{cases} fault cases, seed {seed}, {duration:g} s each")
    for col in ("case", "fault", "level", "onset s", "profile"):
        table.add_column(col)
    units: dict[str, str] = {}
    with progress_bar("plant (machine s)", duration * cases, quiet=quiet) as bar:
        task = bar.task_ids[0]
        for case in drawn:
            rec = run_case(plant, case, duration, rate, progress=lambda s: bar.advance(task, s))
            rec.write(out / f"{case.name}.parquet")
            f = case.faults[0] if case.faults else None
            if f is not None:
                units[f.kind] = f.spec_kind.parameter
            table.add_row(case.name, f"{f.element}:{f.kind} {f.severity:g}" if f else "healthy",
                          case.level or "", f"{f.onset_s:g}" if f else "",
                          ("ramp" if f.ramp_s else "step") if f else "")  # fmt: skip
    manifest = {"seed": seed, "duration_s": duration, "rate_hz": rate,
                "cases": [{**c.describe(), "file": f"{c.name}.parquet"} for c in drawn]}  # fmt: skip
    with atomic_path(out / "cases.json") as tmp:
        tmp.write_text(dumps_strict(manifest, sort_keys=True) + "\n", encoding="utf-8")
    console.print(table)
    for kind, parameter in sorted(units.items()):  # the severity's unit, per kind
        console.print(f"{kind} severity: {parameter}")
    ours = {f"{c.name}.parquet" for c in drawn}
    older = sorted(p.name for p in out.glob("case_*.parquet") if p.name not in ours
                   and not p.name.endswith(".truth.parquet"))  # fmt: skip
    if older:  # not deleted (not this command's to lose), but not of this set either
        err_console.print(f"note: {len(older)} older record(s) in {out} are not of this set "
                          f"({older[0]}...); cases.json lists this set", highlight=False)  # fmt: skip
    console.print(f"wrote {cases} records and {out / 'cases.json'}")


PhysicsOpt = Annotated[str, typer.Option("--model", help="The twin's physics: a model file from "
                       "'drafttwin fit' (its drive train), or preset, preset:NAME, "
                       "config:FILE.toml.", callback=physics_paths("--model"))]  # fmt: skip
RecordOpt = Annotated[str, files_in("--data", "The record to diagnose (.csv/.parquet with a motor column).")]  # fmt: skip
HealthyOpt = Annotated[str | None, files_in("--healthy", (
    "Healthy records of the same machine (comma-separated) to set the thresholds. Default: the "
    "record's own first half (assumed healthy: give --healthy to trust it)."))]  # fmt: skip
ReportOpt = Annotated[Path | None, file_out("--report", "Write an HTML page (timeline, spectrum, drive train).")]  # fmt: skip


@app.command()
@stops_cleanly("nothing was written")
def diagnose(
    model: PhysicsOpt, data: RecordOpt, healthy: HealthyOpt = None,
    far_per_day: FarPerDayOpt = 1.0, as_json: JsonOpt = False, report: ReportOpt = None,
    columns: ColumnsOpt = None, unit_check: UnitCheckOpt = True,
) -> None:  # fmt: skip
    """Detect, locate and size a machine or sensor fault in a record.

    Residuals of the record against the physics (open loop, from the set-points) are watched
    by CUSUM tests whose thresholds come from healthy data for the false-alarm rate asked;
    after an alarm every candidate fault is simulated with the physics and ranked by how well
    it explains the shift of the four rollers and the motor, with its severity and a 95 %
    interval, and the group of candidates these sensors cannot tell apart. p is relative
    among the candidates; each cause's fit (chi-square on its degrees of freedom, p-value)
    is absolute, and when none fits the verdict says that no candidate explains the record.
    An interval cut by a kind's range reads "at least" / "at most"; a fault still growing
    through the window after the alarm (--post) is given with its rate and its severity at
    the window's end. Sensor faults are sized
    in their own unit (a stuck encoder in seconds).

    Gear wear and chain elongation are seen in the rollers' angles (cumulative counts): the
    driven roller trails by the wear depth over the gear's base radius. That needs the record
    to span the change (the angle before and after it; a steady 100-Hz record does), since an
    angle offset alone has no healthy reference. Gear cracks and run-outs are not assessed.
    """
    from drafttwin._json import dumps_strict
    from drafttwin.cli._data import Channels, nominal_rpm, pairs
    from drafttwin.diagnosis.detect import FaultDetector
    from drafttwin.diagnosis.diagnose import Diagnoser
    from drafttwin.diagnosis.physics import physics_train
    from drafttwin.diagnosis.residuals import record_features

    train = physics_train(model)
    mapped = Channels(columns=pairs(columns, "--columns", "v1=front,v2=second") or None,
                      nominal_rpm=nominal_rpm(train), check_units=unit_check)  # fmt: skip
    series = mapped.read(data)
    healthy_paths = [p.strip() for p in (healthy or "").split(",") if p.strip()]
    if healthy_paths:
        tuning = healthy_records(healthy_paths, data, series, mapped)
        tuned_on = healthy
        assumed_until = None
    else:
        cut = len(series) // 2
        tuning = [head_rows(series, cut)]
        tuned_on = f"the record's first {series.time_s[cut - 1] - series.time_s[0]:.0f} s (assumed healthy)"
        assumed_until = float(series.time_s[cut])
    features = []
    for path, record in zip(healthy_paths or [data], tuning, strict=True):
        with _named(path, "--healthy" if healthy_paths else "--data"):
            features.append(record_features(train, record))
    with _named(None, "--healthy" if healthy_paths else "--data (its first half)"):
        detector = FaultDetector(far_per_day=far_per_day).fit(features)
    diagnoser = Diagnoser(train, detector)
    with _named(data, "--data"):
        dx = diagnoser.diagnose(series, first_after=assumed_until)
    watched_from = dx.watched_from_s(detector.reference_s)
    info: dict[str, Any] = {"data": data, "physics": model, "thresholds_from": tuned_on,
            "watched_from_s": watched_from,
            "detector": detector.describe(), "creep_rel_sd": diagnoser.creep_rel_sd}  # fmt: skip
    result = {**info, **dx.to_dict()}
    result["judged"] = dx.judged(detector.reference_s)
    said = {"assumed": assumed_half_note(dx, assumed_until),
            "short": dx.short_note(detector.reference_s),
            "steady": dx.steady_note(detector.reference_s),
            "levels": detector.levels_note(), "lags": detector.lags_note()}  # fmt: skip
    notes = [n for n in said.values() if n is not None]
    if notes:
        result["notes"] = notes
    # the page's banner says the steady one itself
    info["notes"] = [n for k, n in said.items() if n is not None and k != "steady"]
    result["reference_alarms_s"] = inside_alarms(dx, assumed_until)
    from drafttwin.diagnosis.sliver_evidence import sliver_evidence

    sliver = sliver_evidence(data, train, series,
                             healthy=[p.strip() for p in (healthy or "").split(",") if p.strip()])  # fmt: skip
    if sliver is not None:
        result["sliver"] = sliver[0]
    if report is not None:
        from drafttwin._io import atomic_path
        from drafttwin.report.diagnosis import render_diagnosis

        with atomic_path(report) as tmp:
            tmp.write_text(render_diagnosis(dx, train, series, info, sliver=sliver),
                           encoding="utf-8")  # fmt: skip
    if as_json:
        typer.echo(dumps_strict(result))
        return
    print_diagnosis(result, report)
    if sliver is not None:
        print_sliver(sliver[0])


@contextlib.contextmanager
def _named(path: str | None, option: str) -> Iterator[None]:
    """A library error about "the record" or "the tuning data" names the file and option."""
    try:
        yield
    except DrafttwinError as exc:
        if exc.source is None and path is not None:
            exc.source = path
        if exc.where == "tuning" and option.startswith("--data"):  # no --healthy was given
            exc.fix_template = (
                "give --healthy records of this machine, or a longer record "
                "(its first half is the reference when --healthy is left out)"
            )
        if exc.where in ("data", "tuning", None):
            exc.where = option
        raise


QuickOpt = Annotated[bool, typer.Option("--quick", help="A small subset (6 kinds, moderate, abrupt).")]  # fmt: skip
PlanSeedOpt = Annotated[int, number("--seed", "Seed of the plan (machines, recordings, onsets).")]
HealthyHoursOpt = Annotated[float | None, number(
    "--healthy-hours", "Healthy test running in hours, counted after each record's 15-s "
    "reference window (records of the plan's length, 10.5 min full, each its own machine); "
    "default: the plan's (12 x 10.5 min = 2.05 h full, 2 x 1 min quick). A <= 1 per 24 h "
    "claim needs >= 72 h alarm-free.")]  # fmt: skip
RecordsDirOpt = Annotated[Path | None, dir_out("--records", (
    "Folder the plant records are kept in (default OUT/records): made once, read back "
    "checked by later runs (a changed diagnosis re-scores in minutes; a changed plant makes "
    "them again), served by 'benchmark faults --live'."))]  # fmt: skip
LiveOpt = Annotated[bool, typer.Option("--live", help=(
    "Serve the benchmark's records over MQTT to the live twin instead ('plant replay' -> "
    "'twin run', each machine learning its own healthy state first) and score its stored "
    "alarms beside the offline diagnosis of the same records; writes OUT/faults_live.json "
    "and OUT/faults_live.html."))]  # fmt: skip
LiveMachinesOpt = Annotated[int, number("--machines", "--live: machines served at once.")]
_SPEED_HELP = ("--live: times real time per machine (10 machines at 4x: 4000 samples/s, what "
               "one twin process keeps up with on 2 cores).")  # fmt: skip
LiveSpeedOpt = Annotated[float, number("--speed", _SPEED_HELP)]
PlantMachinesOpt = Annotated[int, number("--plant-machines", "--live: machines of the shorter "
                             "run against 'plant serve' (10 min at the wall clock, 6 with --quick; 0: none).")]  # fmt: skip
SliverVariantOpt = Annotated[bool, typer.Option("--sliver", help=(
    "The delivery sensor's variant instead: gear run-out, cracks and roller eccentricity (which "
    "the encoders leave not assessed) recorded with the sliver and placed by its chimneys; "
    "writes OUT/faults_sliver.json."))]  # fmt: skip


@benchmark_app.command("faults")
@stops_cleanly("nothing was written; records already made are kept and reused by a rerun")
def benchmark_faults(
    out: OutDirOpt = Path("faults_out"),
    quick: QuickOpt = False,
    seed: PlanSeedOpt = 0,
    workers: WorkersOpt = 2,
    healthy_hours: HealthyHoursOpt = None,
    as_json: JsonOpt = False,
    quiet: QuietOpt = False,
    sliver: SliverVariantOpt = False,
    records: RecordsDirOpt = None,
    live: LiveOpt = False,
    machines: LiveMachinesOpt = 10,
    speed: LiveSpeedOpt = 4.0,  # studies.faults.live.SPEED (the CLI imports the study lazily)
    plant_machines: PlantMachinesOpt = 4,
) -> None:
    """Seeded faulty and healthy plant records, diagnosed and scored.

    Every fault kind at three severities, abrupt and incipient, on machines of their own;
    thresholds from a separate healthy tuning set; false alarms over healthy running of other
    machines. Scores (detection per severity, delays, false alarms per 24 h, top-1/top-3
    localisation, severity error, sensor faults blamed on the machine, confusion matrix) for
    four methods at the same false-alarm budget: the physics residual, the parallel hybrid's
    residual (both located by the physics ranking), the data-driven (one-step GRU) residual and
    fixed thresholds on raw speeds; both networks are fitted once, on the tuning records only.
    Writes OUT/faults_results.json and OUT/faults_report.html.
    """
    from drafttwin._io import atomic_path
    from drafttwin._json import dumps_strict

    _refuse_unused(sliver, live, healthy_hours, records, machines != 10 or speed != 4.0
                   or plant_machines != 4)  # fmt: skip
    if sliver:
        return _sliver_variant(out, quick, seed, workers, as_json, quiet)
    if live:
        return _live_variant(out, quick, seed, workers, healthy_hours, records,
                             LivePlanArgs(machines, speed, plant_machines), as_json, quiet)  # fmt: skip
    from drafttwin.report.faults_bench import HEAD, render_benchmark, score_rows
    from drafttwin.studies.faults import run_benchmark
    from drafttwin.studies.faults.plan import PLANS, with_healthy_hours

    plan = PLANS["quick" if quick else "full"]
    if healthy_hours is not None:
        plan = with_healthy_hours(plan, healthy_hours)
    with progress_bar(
        f"fault benchmark ({plan.name}): plant records", 1, quiet=quiet or as_json
    ) as bar:
        task = bar.task_ids[0]

        def advance(done: int, total: int) -> None:
            bar.update(task, total=total, completed=done)

        def stage(what: str) -> None:
            bar.update(task, description=f"fault benchmark ({plan.name}): {what}")

        results = run_benchmark(plan, seed, workers, on_record=advance, on_stage=stage,
                                records=records if records is not None else out / "records")  # fmt: skip
    with atomic_path(out / "faults_results.json") as tmp:
        tmp.write_text(dumps_strict(results, sort_keys=True) + "\n", encoding="utf-8")
    with atomic_path(out / "faults_report.html") as tmp:
        tmp.write_text(render_benchmark(results), encoding="utf-8")
    if as_json:
        typer.echo(dumps_strict(results["scores"]))
        return
    table = Table(title=f"fault benchmark ({plan.name}), {results['sets']['faults']} fault records, "
                  f"{results['machine_seconds']['healthy'] / 3600:.2f} h healthy test running")  # fmt: skip
    rows = score_rows(results["scores"])
    table.add_column("score")
    for row in rows:
        table.add_column(row[0], justify="right")
    for i, name in enumerate(HEAD[1:], start=1):  # one line per score, one column per method
        table.add_row(name, *(row[i] for row in rows))
    console.print(table)
    console.print(f"wrote {out / 'faults_results.json'} and {out / 'faults_report.html'}")


def _refuse_unused(sliver: bool, live: bool, healthy_hours: float | None,
                   records: Path | None, live_options: bool) -> None:  # fmt: skip
    """Options the chosen variant would ignore, refused by name (they ran without a word)."""
    given = []
    if sliver:
        given = [name for name, on in (("--live", live), ("--healthy-hours", healthy_hours is not None),
                                       ("--records", records is not None),
                                       ("--machines/--speed/--plant-machines", live_options)) if on]  # fmt: skip
        variant = "--sliver"
    elif not live and live_options:
        given, variant = ["--machines/--speed/--plant-machines"], "the offline benchmark"
    if given:
        more = f" (nor {', '.join(given[1:])})" if len(given) > 1 else ""
        raise ConfigError(f"not used by {variant}{more}", where=given[0],
                          fix="leave it out" if sliver else "add --live for the live twin's "
                          "variant, or leave them out")  # fmt: skip


class LivePlanArgs(NamedTuple):
    machines: int
    speed: float
    plant_machines: int


def _live_variant(out: Path, quick: bool, seed: int, workers: int, healthy_hours: float | None,
                  records: Path | None, args: LivePlanArgs, as_json: bool,
                  quiet: bool) -> None:  # fmt: skip
    from drafttwin._io import atomic_path
    from drafttwin._json import dumps_strict
    from drafttwin.cli.twin_cmds import _need_twin_extra
    from drafttwin.execution.interrupt import stop_on_signals
    from drafttwin.report.faults_bench import HEAD, render_live, score_rows
    from drafttwin.studies.faults.live import LivePlan, run_live
    from drafttwin.studies.faults.plan import PLANS, with_healthy_hours

    _need_twin_extra()
    plan = PLANS["quick" if quick else "full"]
    if healthy_hours is not None:
        plan = with_healthy_hours(plan, healthy_hours)
    with progress_bar(f"live fault benchmark ({plan.name})", 1, quiet=quiet or as_json) as bar:
        task = bar.task_ids[0]

        def stage(what: str) -> None:
            bar.update(task, description=f"live benchmark: {what}")

        def advance(done: int, total: int) -> None:
            bar.update(task, total=total, completed=done)

        with stop_on_signals("the records made so far are kept; the same command reuses them"):
            results = run_live(plan, seed, records if records is not None else out / "records",
                               out / "live", workers=workers,
                               live=LivePlan(machines=args.machines, speed=args.speed,
                                             plant_machines=args.plant_machines,
                                             plant_s=360.0 if quick else 600.0),
                               on_stage=stage, on_progress=advance)  # fmt: skip
    with atomic_path(out / "faults_live.json") as tmp:
        tmp.write_text(dumps_strict(results, sort_keys=True) + "\n", encoding="utf-8")
    with atomic_path(out / "faults_live.html") as tmp:
        tmp.write_text(render_live(results), encoding="utf-8")
    both = {"offline": results["offline"]["scores"], "live twin": results["twin"]["scores"]}
    if as_json:
        typer.echo(dumps_strict(both))
        return
    lv = results["live"]
    table = Table(title=f"live fault benchmark ({plan.name}): "
                  f"{results['machine_hours_served']:.1f} machine-hours served on "
                  f"{lv['machines']} machines at {lv['speed']:g}x, {lv['wall_s'] / 60:.1f} min")  # fmt: skip
    table.add_column("score")
    rows = score_rows(both)
    for row in rows:
        table.add_column(row[0], justify="right")
    for i, name in enumerate(HEAD[1:], start=1):
        table.add_row(name, *(row[i] for row in rows))
    console.print(table)
    console.print(f"received {lv['received']} of {lv['published']} samples, {lv['dropped']} "
                  f"dropped")  # fmt: skip
    plant = results.get("plant")
    if plant:
        pt = Table(title=f"the live plant: {plant['machines']} machines served for "
                   f"{plant['duration_s'] / 60:.0f} min, a fault each at a random time")  # fmt: skip
        pt.add_column("score")
        prow = score_rows({"recorded, offline": plant["offline"]["scores"],
                           "served, live twin": plant["twin"]["scores"]})  # fmt: skip
        for row in prow:
            pt.add_column(row[0], justify="right")
        for i, name in enumerate(HEAD[1:], start=1):
            pt.add_row(name, *(row[i] for row in prow))
        console.print(pt)
    console.print(f"wrote {out / 'faults_live.json'} and {out / 'faults_live.html'}")


def _sliver_variant(out: Path, quick: bool, seed: int, workers: int, as_json: bool,
                    quiet: bool) -> None:  # fmt: skip
    from drafttwin._io import atomic_path
    from drafttwin._json import dumps_strict
    from drafttwin.studies.faults import sliver as variant

    with progress_bar("fault benchmark, sliver variant: records", 1,
                      quiet=quiet or as_json) as bar:  # fmt: skip
        task = bar.task_ids[0]
        results = variant.run(seed, quick, workers,
                              on_record=lambda d, t: bar.update(task, total=t, completed=d))  # fmt: skip
    with atomic_path(out / "faults_sliver.json") as tmp:
        tmp.write_text(dumps_strict(results, sort_keys=True) + "\n", encoding="utf-8")
    scores = results["scores"]
    if as_json:
        typer.echo(dumps_strict(scores))
        return
    table = Table(title="the sliver places: a chimney at the element's line (found), named "
                  "first, or among the first's look-alikes (group); 'new': against the record's "
                  "own sliver before the onset")  # fmt: skip
    for col in ("fault", "n", "found", "first", "group", "new: found", "new: first"):
        table.add_column(col, justify="left" if col == "fault" else "right")
    for key, s in scores["per_kind_level"].items():
        table.add_row(key, str(s["records"]), str(s["detected"]), str(s["top1"]), str(s["group"]),
                      str(s["new_detected"]), str(s["new_top1"]))  # fmt: skip
    console.print(table)
    console.print(f"healthy machines: {scores['healthy_chimneys']} chimneys in "
                  f"{scores['healthy_sliver_m']:.0f} m of sliver "
                  f"({scores['healthy_records_with_chimney']} of {scores['healthy_records']} "
                  "records" + "".join(f"; at {c['wavelength_m'] * 100:.2f} cm ({c['cause']})"
                                      for c in scores["healthy_lines"])
                  + f"); new against the record's own first {10:g} s: "
                  f"{scores['healthy_new_chimneys']}; the encoders' diagnosis leaves these kinds "
                  "not assessed (docs/faults.md)")  # fmt: skip
    console.print(f"wrote {out / 'faults_sliver.json'}")
