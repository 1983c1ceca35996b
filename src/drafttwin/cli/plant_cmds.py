"""``drafttwin generate``: run the plant emulator and write measured data."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.table import Table

from drafttwin.cli._common import check_output_suffix, load_train
from drafttwin.cli.app import app, console, progress_bar
from drafttwin.cli.mechanics_cmds import ConfigOpt, PresetOpt


@app.command()
def generate(
    out: Annotated[Path, typer.Option(help="Measured data file, .csv or .parquet.")],
    preset: PresetOpt = None,
    config: ConfigOpt = None,
    duration: Annotated[float, typer.Option(help="Recorded machine time, s.", min=0)] = 60.0,
    rate: Annotated[float, typer.Option(help="Sample rate, Hz.", min=0)] = 100.0,
    seed: Annotated[int, typer.Option(help="Seed: same seed, byte-identical files.")] = 0,
    scenario: Annotated[
        str, typer.Option(help="steady | startup | speed-change (see docs/plant.md).")
    ] = "steady",
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
) -> None:
    """Run the plant emulator: measured roller speeds with the machine's real imperfections.

    Writes OUT (time, front, second, third, back in rpm, gaps as empty cells, and the VFD
    set-point supply_hz), OUT's .truth file (true speeds, where samples were dropped or
    spiked) and OUT's .json sidecar (seed, true parameters, effects).
    """
    from drafttwin.plant import Plant
    from drafttwin.plant.scenarios import get_scenario

    check_output_suffix(out)
    get_scenario(scenario)
    plant = Plant(load_train(preset, config))
    with progress_bar("plant (machine s)", duration, quiet=quiet) as bar:
        task = bar.task_ids[0]
        rec = plant.run(duration, rate, seed=seed, scenario=scenario,
                        progress=lambda s: bar.advance(task, s))  # fmt: skip
    paths = rec.write(out)
    table = Table(title=f"plant, scenario '{scenario}', seed {seed}: {duration:g} s at {rate:g} Hz")
    for col in ("roller", "mean rpm", "true std %", "missing", "spikes", "noise rms rpm"):
        table.add_column(col, justify="right" if col != "roller" else "left")
    for j, name in enumerate(rec.series.channels):
        x, t = rec.series.values[:, j], rec.true_rpm[:, j]
        ok = ~np.isnan(x) & ~rec.outlier[:, j]
        noise = float(np.sqrt(np.mean((x[ok] - t[ok]) ** 2)))
        table.add_row(name, f"{np.nanmean(x):.2f}", f"{t.std() / t.mean() * 100:.4f}",
                      str(int(rec.missing[:, j].sum())), str(int(rec.outlier[:, j].sum())),
                      f"{noise:.3f}")  # fmt: skip
    console.print(table)
    console.print("wrote " + ", ".join(str(p) for p in paths))
