"""``drafttwin benchmark emps``: validation on real measurements (the EMPS benchmark)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from drafttwin.cli._bounds import bounded
from drafttwin.cli._oserrors import input_path, output_dir
from drafttwin.cli.app import app, console, print_json, progress_bar

benchmark_app = typer.Typer(
    help="Validation benchmarks on real measured data (see docs/emps.md).",
    no_args_is_help=True,
)
app.add_typer(benchmark_app, name="benchmark")


def _names(text: str) -> tuple[str, ...]:
    return tuple(s.strip().lower() for s in text.split(",") if s.strip())


@benchmark_app.command("emps")
def emps(
    data_dir: Annotated[
        Path | None,
        typer.Option(
            help="Folder with DATA_EMPS.mat and DATA_EMPS_PULSES.mat (default: "
            "$DRAFTTWIN_EMPS_DIR).",
            callback=input_path("--data-dir"),
        ),
    ] = None,
    seeds: Annotated[
        int, typer.Option(help="Seeds per trained model.", callback=bounded("--seeds"))
    ] = 3,
    profile: Annotated[str, typer.Option(help="quick | standard | paper.")] = "quick",
    out: Annotated[Path, typer.Option(help="Output folder.", callback=output_dir("--out"))] = Path(
        "emps_out"
    ),
    models: Annotated[
        str, typer.Option(help="Comma-separated subset of the models.")
    ] = "mechanistic,persistence,gru,lstm,parallel,md-s-l",
    tasks: Annotated[str, typer.Option(help="simulation,prediction or one of them.")] = (
        "simulation,prediction"
    ),
    workers: Annotated[
        int, typer.Option(help="Parallel processes.", callback=bounded("--workers"))
    ] = 1,
    epochs: Annotated[
        int | None,
        typer.Option(help="Override the profile's epoch budget.", callback=bounded("--epochs")),
    ] = None,
    max_samples: Annotated[
        int | None,
        typer.Option(
            help="Use only the first N samples of each record (smoke tests; not the "
            "official protocol).",
            callback=bounded("--max-samples"),
        ),
    ] = None,
    train_metrics: Annotated[
        bool, typer.Option(help="Also score every model on the training record.")
    ] = False,
    device: Annotated[str, typer.Option(help="auto | cpu | cuda.")] = "auto",
    as_json: Annotated[bool, typer.Option("--json", help="Print the results as JSON.")] = False,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
) -> None:
    """Physics only, black-box GRU/LSTM, parallel hybrid and MD-S-L on the EMPS benchmark.

    Official split (train DATA_EMPS, test DATA_EMPS_PULSES), input vir, output qm, free-run
    simulation from the first 20 test samples, RMSE in mm over the rest; every model also in
    one-step prediction mode (reported apart). Prints the table beside the published numbers
    and writes OUT/emps_report.html, OUT/emps_results.json and OUT/emps_predictions.csv.
    """
    from drafttwin.benchmarks.emps.run import EmpsConfig, run_benchmark, task_configs
    from drafttwin.datasets.emps import load_emps
    from drafttwin.report.emps import HEADER, table_rows, write_outputs

    config = EmpsConfig(
        data_dir=data_dir, seeds=seeds, profile=profile, models=_names(models),
        tasks=_names(tasks), epochs=epochs, max_samples=max_samples,
        train_metrics=train_metrics, workers=workers, device=device,
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
    table = Table(title=f"EMPS test record, profile {profile}, {seeds} seed(s)")
    for col in HEADER:
        table.add_column(col, justify="left" if col in ("model", "task") else "right")
    for cells in table_rows(result.results):
        table.add_row(*cells)
    console.print(table)
    console.print(
        "published: physics 9.23 mm (README computation), LSTM 74.1 mm and GRU 220.3 mm "
        "(Champneys et al. 2024, trained on half of DATA_EMPS); prediction-mode rows are "
        "one-step-ahead and not comparable with them."
    )
    console.print("wrote " + ", ".join(str(p) for p in paths))


@benchmark_app.command("generalisation")
def generalisation(
    quick: Annotated[
        bool,
        typer.Option(
            "--quick",
            help="A small subset (short records, tiny networks, 1 seed, 2 training lengths) "
            "that runs in about a minute: a smoke test, not the benchmark's figures.",
        ),
    ] = False,
    seeds: Annotated[
        int | None,
        typer.Option(
            help="Seeds per learned model (default: 3, quick 1).", callback=bounded("--seeds")
        ),  # fmt: skip
    ] = None,
    workers: Annotated[
        int, typer.Option(help="Parallel processes for the fits.", callback=bounded("--workers"))
    ] = 1,
    out: Annotated[Path, typer.Option(help="Output folder.", callback=output_dir("--out"))] = Path(
        "generalisation_out"
    ),
    cache: Annotated[
        bool,
        typer.Option(
            help="Keep the plant records and finished fits in OUT/cache and reuse "
            "them on a rerun of the same configuration."
        ),  # fmt: skip
    ] = True,
    as_json: Annotated[
        bool,
        typer.Option("--json", help='Print {"rows": [...], "floors": [...]} (strict JSON).'),
    ] = False,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
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
    from drafttwin.benchmarks.generalisation import get_config, run_benchmark
    from drafttwin.report.generalisation import check_lines, extrapolation_rows, write_outputs

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
