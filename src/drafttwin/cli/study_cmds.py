"""``drafttwin reproduce`` and ``drafttwin grid-search``: the paper's study."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from drafttwin.cli._groups import with_group
from drafttwin.cli._options import ColumnsOpt, QuietOpt, dir_out, files_in, number
from drafttwin.cli._oserrors import no_input_among
from drafttwin.cli.typer_app import app, console, err_console

if TYPE_CHECKING:
    from drafttwin.data.series import MeasurementSeries
    from drafttwin.studies.paper.run import Study

PlanOpt = Annotated[
    str,
    typer.Option(
        "--plan",
        "--profile",
        help="Study plan (--plan or --profile): quick (minutes on a laptop CPU) | standard | "
        "paper (GPU recommended).",
    ),
]
ExecOpt = Annotated[str, typer.Option(help="local (process pool) | ray.")]
AddrOpt = Annotated[str | None, typer.Option(help="Ray cluster address (HOST:PORT or 'auto'); "
                    "none: a private local Ray instance.")]  # fmt: skip
StudyDataOpt = Annotated[str, files_in("--data", "'default' or a CSV/Parquet measurement file.")]
WorkersOpt = Annotated[int | None, number("--workers", "Parallel tasks (default: CPU cores, at "
                       "most 8; at most 4 per core).")]  # fmt: skip
StudyOutOpt = Annotated[Path, dir_out("--out", "Output folder (report.html, results.json, CSV tables).")]  # fmt: skip
GridOutOpt = Annotated[Path, dir_out("--out", "Output folder (grid.json and the task cache).")]
GeneralisationOpt = Annotated[bool, typer.Option(help=(
    "Add the section 'Where does the physics pay?' from the generalisation benchmark's quick "
    "subset (about 20 s of CPU; kept in OUT/cache/generalisation)."))]  # fmt: skip


class _Display:
    """Stage, task k of n and elapsed time on stderr; silent when quiet."""

    def __init__(self, quiet: bool) -> None:
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
        )

        self.progress = Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                                 TimeElapsedColumn(), console=err_console, disable=quiet)  # fmt: skip

    def stage(self, name: str, total: int) -> Callable[[int, dict[str, Any], bool], None]:
        task = self.progress.add_task(name, total=total)

        def tick(index: int, result: dict[str, Any], cached: bool) -> None:
            self.progress.advance(task)

        return tick


def _physics_pays(out: Path, display: _Display) -> dict[str, Any]:
    """The generalisation benchmark's quick subset, summarised for the study report."""
    from drafttwin.report.generalisation import study_summary
    from drafttwin.studies.generalisation import get_config, run_benchmark

    task = display.progress.add_task("where the physics pays (quick benchmark)", total=1)

    def tick(stage: str, done: int, total: int) -> None:
        display.progress.update(task, description=f"where the physics pays: {stage}",
                                completed=done, total=total)  # fmt: skip

    doc = run_benchmark(get_config(True), tick, cache_dir=out / "cache" / "generalisation")
    return study_summary(doc)


def _resume_note(out: Path) -> str:
    return f"finished results are kept in {out}, rerun to resume"


@dataclass(frozen=True)
class StudyOptions:
    """What both study commands take (an option group)."""

    plan: PlanOpt = "quick"
    data: StudyDataOpt = "default"
    columns: ColumnsOpt = None
    executor: ExecOpt = "local"
    address: AddrOpt = None
    workers: WorkersOpt = None
    quiet: QuietOpt = False

    def study(self, out: Path) -> tuple[Study, MeasurementSeries, _Display]:
        from drafttwin.cli._data import Channels, pairs
        from drafttwin.execution import check_executor
        from drafttwin.studies.paper.run import Study

        check_executor(self.executor, self.workers, self.address)  # before the data are read
        columns = pairs(self.columns, "--columns", "v1=front,v2=second") or None
        series = Channels(columns=columns).read(self.data)
        display = _Display(self.quiet)
        study = Study(self.plan, out_dir=out, executor=self.executor, address=self.address,
                      workers=self.workers, stage=display.stage)  # fmt: skip
        study.data_name = self.data
        return study, series, display


@app.command()
@with_group("options", StudyOptions)
def reproduce(
    options: StudyOptions,
    out: StudyOutOpt = Path("drafttwin-study"),
    generalisation: GeneralisationOpt = True,
) -> None:
    """Run the paper's whole study and write a self-contained HTML report.

    Grid search (Fig. 7), model comparison (Table 2, Fig. 8) with honest metrics, ablation over 10 repeated tests (Table 3).

    Finished fits are kept in OUT/cache: a rerun resumes.
    """
    from drafttwin.execution.interrupt import stop_on_signals
    from drafttwin.execution.lock import study_lock
    from drafttwin.report import write_study
    from drafttwin.report.writer import STUDY_FILES

    no_input_among(out, STUDY_FILES, "--out")
    t0 = time.perf_counter()
    study, series, display = options.study(out)
    # one run at a time per --out; a signal stops the run cleanly and leaves it resumable
    with study_lock(out), stop_on_signals(_resume_note(out)), display.progress:
        results, predictions = study.run(series)
        if generalisation:
            start = time.perf_counter()
            results["generalisation"] = _physics_pays(out, display)
            took = time.perf_counter() - start  # a stage of the run: the report's total has it
            results["timings"]["stages"]["where the physics pays"] = took
            results["timings"]["total_s"] += took
        files = write_study(out, results, predictions)
    console.print(
        f"study '{options.plan}' done in {time.perf_counter() - t0:.0f} s; report: "
        f"{files['report']}"
    )
    for name, path in files.items():
        console.print(f"  {name:12s} {path}")


@app.command("grid-search")
@with_group("options", StudyOptions)
def grid_search(
    options: StudyOptions,
    out: GridOutOpt = Path("drafttwin-study"),
) -> None:
    """The paper's grid search only: lr x hidden x layers for LSTM and GRU (Fig. 7)."""
    from drafttwin._io import write_text_atomic
    from drafttwin._json import dumps_strict
    from drafttwin.execution.interrupt import stop_on_signals
    from drafttwin.execution.lock import study_lock

    no_input_among(out, ("grid.json",), "--out")
    study, series, display = options.study(out)
    with study_lock(out), stop_on_signals(_resume_note(out)), display.progress:
        study.prepare_data(series)
        grid = study.grid()
        write_text_atomic(out / "grid.json", dumps_strict(grid) + "\n")
    for net in ("lstm", "gru"):
        b = grid["best"][net]
        console.print(f"{net.upper()}: best lr {b['lr']:g}, hidden {b['hidden']}, layers {b['layers']} "
                      f"(validation loss {b['val_loss']:.3g})")  # fmt: skip
    console.print(f"wrote {out / 'grid.json'}")
