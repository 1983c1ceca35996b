"""``drafttwin reproduce`` and ``drafttwin grid-search``: the paper's study."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from drafttwin.cli.app import app, console, err_console

ProfileOpt = Annotated[
    str, typer.Option(help="quick (minutes on a laptop CPU) | standard | paper (GPU recommended).")
]
ExecOpt = Annotated[str, typer.Option(help="local (process pool) | ray.")]
AddrOpt = Annotated[
    str | None,
    typer.Option(
        help="Ray cluster address (HOST:PORT or 'auto'); none: a private local Ray instance."
    ),
]
StudyDataOpt = Annotated[str, typer.Option(help="'default' or a CSV/Parquet measurement file.")]
QuietOpt = Annotated[bool, typer.Option(help="No progress display.")]
WorkersOpt = Annotated[
    int | None, typer.Option(help="Parallel tasks (default: CPU cores, at most 8).", min=1)
]


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

    def stage(self, name: str, total: int):
        task = self.progress.add_task(name, total=total)

        def tick(index: int, result: dict, cached: bool) -> None:
            self.progress.advance(task)

        return tick


def _study(
    profile: str,
    out: Path,
    data: str,
    executor: str,
    address: str | None,
    workers: int | None,
    quiet: bool,
):
    from drafttwin.cli._data import Channels
    from drafttwin.experiments.study import Study

    series = Channels().read(data)
    display = _Display(quiet)
    study = Study(
        profile,
        out_dir=out,
        executor=executor,
        address=address,
        workers=workers,
        stage=display.stage,
    )
    study.data_name = data
    return study, series, display


@app.command()
def reproduce(
    profile: ProfileOpt = "quick",
    out: Annotated[
        Path, typer.Option(help="Output folder (report.html, results.json, CSV tables).")
    ] = Path("drafttwin-study"),
    data: StudyDataOpt = "default",
    executor: ExecOpt = "local",
    address: AddrOpt = None,
    workers: WorkersOpt = None,
    quiet: QuietOpt = False,
) -> None:
    """Run the paper's whole study and write a self-contained HTML report.

    Grid search (Fig. 7), model comparison (Table 2, Fig. 8) with honest metrics, ablation over 10 repeated tests (Table 3).

    Finished fits are kept in OUT/cache: a rerun resumes.
    """
    from drafttwin.report import write_study

    t0 = time.perf_counter()
    study, series, display = _study(profile, out, data, executor, address, workers, quiet)
    with display.progress:
        results, predictions = study.run(series)
    files = write_study(out, results, predictions)
    console.print(
        f"study '{profile}' done in {time.perf_counter() - t0:.0f} s; report: {files['report']}"
    )
    for name, path in files.items():
        console.print(f"  {name:12s} {path}")


@app.command("grid-search")
def grid_search(
    profile: ProfileOpt = "quick",
    out: Annotated[Path, typer.Option(help="Output folder (grid.json and the task cache).")] = Path(
        "drafttwin-study"
    ),
    data: StudyDataOpt = "default",
    executor: ExecOpt = "local",
    address: AddrOpt = None,
    workers: WorkersOpt = None,
    quiet: QuietOpt = False,
) -> None:
    """The paper's grid search only: lr x hidden x layers for LSTM and GRU (Fig. 7)."""
    import json

    from drafttwin._io import write_text_atomic

    study, series, display = _study(profile, out, data, executor, address, workers, quiet)
    with display.progress:
        study.prepare_data(series)
        grid = study.grid()
    write_text_atomic(out / "grid.json", json.dumps(grid, indent=2) + "\n")
    for net in ("lstm", "gru"):
        b = grid["best"][net]
        console.print(f"{net.upper()}: best lr {b['lr']:g}, hidden {b['hidden']}, layers {b['layers']} "
                      f"(validation loss {b['val_loss']:.3g})")  # fmt: skip
    console.print(f"wrote {out / 'grid.json'}")
