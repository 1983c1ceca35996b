"""``drafttwin benchmark emps``: validation on real measurements (the EMPS benchmark)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from drafttwin.cli._groups import stops_cleanly
from drafttwin.cli._options import (
    EpochsOpt,
    JsonOpt,
    OutDirOpt,
    QuietOpt,
    WorkersOpt,
    number,
    path_in,
)
from drafttwin.cli.typer_app import app, console, print_json, progress_bar

benchmark_app = typer.Typer(
    help="Validation benchmarks on real measured data (see docs/emps.md).",
    no_args_is_help=True,
)
app.add_typer(benchmark_app, name="benchmark")


def _names(text: str) -> tuple[str, ...]:
    return tuple(s.strip().lower() for s in text.split(",") if s.strip())


EmpsDirOpt = Annotated[Path | None, path_in("--data-dir", "Folder with DATA_EMPS.mat and "
                      "DATA_EMPS_PULSES.mat (default: $DRAFTTWIN_EMPS_DIR).")]  # fmt: skip
EmpsSeedsOpt = Annotated[int, number("--seeds", "Seeds per trained model.")]
ProfileOpt = Annotated[str, typer.Option("--profile", help="quick | standard | paper.")]
ModelsOpt = Annotated[str, typer.Option("--models", help="Comma-separated subset of the models.")]
TasksOpt = Annotated[str, typer.Option("--tasks", help="simulation,prediction or one of them.")]
MaxSamplesOpt = Annotated[int | None, number("--max-samples", "Use only the first N samples of "
                          "each record (smoke tests; not the official protocol).")]  # fmt: skip
# derived from the parameter's name, as --train-metrics/--no-train-metrics
TrainMetricsOpt = Annotated[bool, typer.Option(help="Also score every model on the training record.")]  # fmt: skip
DeviceOpt = Annotated[str, typer.Option("--device", help="auto | cpu | cuda.")]
PhysicsOpt = Annotated[str, typer.Option("--physics", help=(
    "published | refitted | both: the physics that physics only and the hybrids use; refitted "
    "= M, Fv, Fc, offset refitted by output error on the training record."))]  # fmt: skip


@benchmark_app.command("emps")
@stops_cleanly("nothing was written")
def emps(
    data_dir: EmpsDirOpt = None,
    seeds: EmpsSeedsOpt = 3,
    profile: ProfileOpt = "quick",
    out: OutDirOpt = Path("emps_out"),
    models: ModelsOpt = "mechanistic,persistence,gru,lstm,parallel,md-s-l",
    tasks: TasksOpt = "simulation,prediction",
    workers: WorkersOpt = 1,
    epochs: EpochsOpt = None,
    max_samples: MaxSamplesOpt = None,
    train_metrics: TrainMetricsOpt = False,
    device: DeviceOpt = "auto",
    physics: PhysicsOpt = "published",
    as_json: JsonOpt = False,
    quiet: QuietOpt = False,
) -> None:
    """Physics only, black-box GRU/LSTM, parallel hybrid and MD-S-L on the EMPS benchmark.

    Official split (train DATA_EMPS, test DATA_EMPS_PULSES), input vir, output qm, free-run
    simulation from the first 20 test samples, RMSE in mm over the rest; every model also in
    one-step prediction mode (reported apart). Prints the table beside the published numbers
    and writes OUT/emps_report.html, OUT/emps_results.json and OUT/emps_predictions.csv.
    """
    from drafttwin.datasets.emps import load_emps
    from drafttwin.report.emps import HEADER, refit_line, table_rows, write_outputs
    from drafttwin.studies.emps.plan import PHYSICS, EmpsConfig, task_configs
    from drafttwin.studies.emps.run import run_benchmark

    config = EmpsConfig(
        data_dir=data_dir, seeds=seeds, profile=profile, models=_names(models),
        tasks=_names(tasks), epochs=epochs, max_samples=max_samples,
        train_metrics=train_metrics, workers=workers, device=device,
        physics_variants=PHYSICS if physics.strip().lower() == "both" else _names(physics),
    )  # fmt: skip
    config.check()
    load_emps(data_dir)  # refuse missing or altered files before anything starts
    total = len(task_configs(config))
    with progress_bar("EMPS benchmark (model fits)", total, quiet=quiet or as_json) as bar:
        task = bar.task_ids[0]
        result = run_benchmark(config, progress=lambda _r: bar.advance(task, 1))
    paths = write_outputs(result, out)
    if as_json:
        print_json(result.results["rows"])
        return
    override = f", {epochs} epoch(s) (--epochs: not the benchmark's figures)" if epochs else ""
    table = Table(title=f"EMPS test record, profile {profile}, {seeds} seed(s){override}")
    for col in HEADER:
        table.add_column(col, justify="left" if col in ("model", "task") else "right")
    for cells in table_rows(result.results):
        table.add_row(*cells)
    console.print(table)
    if refit_line(result.results):
        console.print(refit_line(result.results))
    console.print(
        "published: physics 9.23 mm (README computation), LSTM 74.1 mm and GRU 220.3 mm "
        "(Champneys et al. 2024, trained on half of DATA_EMPS); prediction-mode rows are "
        "one-step-ahead and not comparable with them."
    )
    console.print("wrote " + ", ".join(str(p) for p in paths))


QuickOpt = Annotated[bool, typer.Option("--quick", help=(
    "A small subset (short records, tiny networks, 1 seed, 2 training lengths) that runs in "
    "about a minute: a smoke test, not the benchmark's figures."))]  # fmt: skip
SeedsOpt = Annotated[int | None, number("--seeds", "Seeds per learned model (default: 3, quick 1).")]  # fmt: skip
# derived from the parameter's name, as --cache/--no-cache
CacheOpt = Annotated[bool, typer.Option(help="Keep the plant records and finished fits in "
                     "OUT/cache and reuse them on a rerun of the same configuration.")]  # fmt: skip
RowsJsonOpt = Annotated[bool, typer.Option("--json", help='Print {"rows": [...], "floors": [...]} (strict JSON).')]  # fmt: skip


@benchmark_app.command("generalisation")
@stops_cleanly(
    "finished records and fits are kept in OUT/cache (unless --no-cache): a rerun resumes"
)
def generalisation(
    quick: QuickOpt = False,
    seeds: SeedsOpt = None,
    workers: WorkersOpt = 1,
    out: OutDirOpt = Path("generalisation_out"),
    cache: CacheOpt = True,
    as_json: RowsJsonOpt = False,
    quiet: QuietOpt = False,
) -> None:
    """Where does the physics pay? Models trained on steady running of one machine at one
    set-point, tested where their training never went.

    Scenarios: speed+10, speed-10, speed+25, speed-25 (other set-points), speed-change,
    start-up, stop, draft-gears (other draft change gears: the physics gets the new gear set,
    the learned models only the data), other-machine (another machine of the type; nominal and
    calibrated physics), little-data (learning curves: 10, 30, 90, 300 s of training, 3 seeds).
    Tasks prediction (one step) and simulation (free run from the set-point with a short
    measured start); models mechanistic, persistence, gru, parallel, md-s-l. The hybrids'
    structure (absolute or relative to the physics' speed; correction not faded, faded
    outside the training range, or strictly: also off where a set-point leaves its training
    value) is chosen on three validation records (steady at +15 % and -15 % speed, a speed
    change from +15 %), against the physics. Writes
    OUT/generalisation_report.html and OUT/generalisation_results.json (docs/generalisation.md).
    """
    from drafttwin.report.generalisation import check_lines, extrapolation_rows, write_outputs
    from drafttwin.studies.generalisation import get_config, run_benchmark

    changes: dict[str, int] = {"workers": workers}
    if seeds is not None:
        changes["seeds"] = seeds
    config = get_config(quick, **changes)
    config.check()
    with progress_bar("plant records", 1, quiet=quiet or as_json) as bar:
        task = bar.task_ids[0]

        def report(stage: str, done: int, total: int) -> None:
            bar.update(task, description=stage, completed=done, total=total)

        doc = run_benchmark(config, report, cache_dir=(out / "cache") if cache else None)
    paths = write_outputs(doc, out)
    if as_json:
        print_json(doc)
        return
    head, rows = extrapolation_rows(doc, "simulation")
    table = Table(title=f"free-run RMSE, rpm ({config.name}, {config.seeds} seed(s))")
    for col in head:
        table.add_column(col, justify="left" if col in ("scenario", "roller") else "right")
    for cells in rows:
        table.add_row(*cells)
    console.print(table)
    for line in check_lines(doc):
        console.print(line)
    console.print("wrote " + ", ".join(str(p) for p in paths))
