"""``drafttwin generate-faults``: seeded healthy and faulty plant records with labels."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from drafttwin._limits import check_rk4_steps, check_samples
from drafttwin.cli._bounds import bounded
from drafttwin.cli._common import load_train
from drafttwin.cli._oserrors import output_dir
from drafttwin.cli.app import app, console, progress_bar
from drafttwin.cli.mechanics_cmds import ConfigOpt, PresetOpt


@app.command("generate-faults")
def generate_faults(
    out: Annotated[
        Path,
        typer.Option(help="Folder for the records and cases.json.", callback=output_dir("--out")),
    ],
    cases: Annotated[
        int, typer.Option(help="Number of records (one in 4 healthy).", callback=bounded("--cases"))
    ] = 12,
    seed: Annotated[
        int,
        typer.Option(
            help="Seed of the whole set: same seed, same files.", callback=bounded("--seed")
        ),
    ] = 0,
    duration: Annotated[
        float, typer.Option(help="Machine time per record, s.", callback=bounded("--duration"))
    ] = 60.0,
    rate: Annotated[
        float, typer.Option(help="Sample rate, Hz.", callback=bounded("--rate"))
    ] = 100.0,
    preset: PresetOpt = None,
    config: ConfigOpt = None,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
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

    plant = Plant(load_train(preset, config))
    check_samples(duration, rate, where="--duration, --rate")
    check_rk4_steps(duration * cases, plant.train.spec.solver.dt_s, where="--duration, --cases")
    drawn = draw_cases(plant.train, cases, seed, duration)
    table = Table(title=f"{cases} fault cases, seed {seed}, {duration:g} s each")
    for col in ("case", "fault", "level", "onset s", "profile"):
        table.add_column(col)
    with progress_bar("plant (machine s)", duration * cases, quiet=quiet) as bar:
        task = bar.task_ids[0]
        for case in drawn:
            rec = run_case(plant, case, duration, rate, progress=lambda s: bar.advance(task, s))
            rec.write(out / f"{case.name}.parquet")
            f = case.faults[0] if case.faults else None
            table.add_row(case.name, f"{f.element}:{f.kind} {f.severity:g}" if f else "healthy",
                          case.level or "", f"{f.onset_s:g}" if f else "",
                          ("ramp" if f.ramp_s else "step") if f else "")  # fmt: skip
    manifest = {"seed": seed, "duration_s": duration, "rate_hz": rate,
                "cases": [{**c.describe(), "file": f"{c.name}.parquet"} for c in drawn]}  # fmt: skip
    with atomic_path(out / "cases.json") as tmp:
        tmp.write_text(dumps_strict(manifest, sort_keys=True) + "\n", encoding="utf-8")
    console.print(table)
    console.print(f"wrote {cases} records and {out / 'cases.json'}")
