"""``drafttwin benchmark leveller``: the twin's action point against the simulated CV minimum."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from rich import box
from rich.table import Table

from drafttwin.cli._groups import stops_cleanly
from drafttwin.cli._options import JsonOpt, OutDirOpt, QuietOpt, WorkersOpt, number
from drafttwin.cli.benchmark_cmds import benchmark_app
from drafttwin.cli.typer_app import console, print_json, progress_bar

QuickLevelOpt = Annotated[bool, typer.Option("--quick", help="Two machines and no fault case "
                          "(unless --machines / --fault-cases say otherwise), 80 m records, eight "
                          "fibres lumped into one (a smoke run, minutes).")]  # fmt: skip
MachinesLevelOpt = Annotated[int | None, number("--machines", "Machines with the leveller at a wrong action point (default 10, --quick 2).")]  # fmt: skip
FaultCasesOpt = Annotated[int | None, number("--fault-cases", "Machines with a sluggish drive or a drifting infeed sensor, in turn (default 4, --quick 0).")]  # fmt: skip
PlanSeedLevelOpt = Annotated[int, number("--seed", "Seed of the plan (machines, feed faults, settings).")]  # fmt: skip


@benchmark_app.command("leveller")
@stops_cleanly("finished machines are kept in OUT/cases: a rerun resumes")
def benchmark_leveller(
    out: OutDirOpt = Path("leveller_out"),
    quick: QuickLevelOpt = False,
    machines: MachinesLevelOpt = None,
    fault_cases: FaultCasesOpt = None,
    seed: PlanSeedLevelOpt = 0,
    workers: WorkersOpt = 1,
    as_json: JsonOpt = False,
    quiet: QuietOpt = False,
) -> None:
    """Seeded plant machines with a feed fault (long-wave count variation, a sliver running
    out, piecings) and the leveller at a wrong action point (fault cases: a sluggish drive, a
    drifting infeed sensor): 'sliver level' on each record (at most 300 m of sliver) against
    the simulated CV minimum over the action point (Brent's method, every fibre drafted
    again at each setting). Writes OUT/leveller_results.json; finished machines are kept in
    OUT/cases and not run again by the same code."""
    from dataclasses import replace

    from drafttwin._io import atomic_path
    from drafttwin._json import dumps_strict
    from drafttwin.studies.leveller import LevellerBenchConfig, run_benchmark

    config = LevellerBenchConfig.quick(seed) if quick else LevellerBenchConfig(seed=seed)
    given = {"machines": machines, "fault_cases": fault_cases}  # --quick takes them too
    config = replace(config, **{k: v for k, v in given.items() if v is not None})
    total = config.machines + config.fault_cases
    with progress_bar("leveller benchmark (machines)", total, quiet=quiet or as_json) as bar:
        task = bar.task_ids[0]
        results = run_benchmark(config, workers, out / "cases",
                                lambda done, n: bar.update(task, completed=done))  # fmt: skip
    with atomic_path(out / "leveller_results.json") as tmp:
        tmp.write_text(dumps_strict(results, sort_keys=True) + "\n", encoding="utf-8")
    if as_json:
        print_json(results["summary"])
        return
    _print(results)
    console.print(f"wrote {out / 'leveller_results.json'}")


def _short(fault: str | None) -> str:
    return {"sluggish-drive": "drive", "infeed-drift": "drift"}.get(fault or "", "")


def _print(results: dict[str, Any]) -> None:
    table = Table(title="recommended action point (rec) against the simulated CV minimum (min "
                  "at), mm; set: the record's setting off the true point; CV %",
                  box=box.SIMPLE_HEAD, pad_edge=False, padding=0)  # fmt: skip
    # never cut: at 80 columns the CVs read "1.6…" and the feed "long…" (the words fold)
    widths = {"": 2, "feed": 9, "fault": 5, "ratio": 5, "m": 4}
    for col in ("", "feed", "fault", "set mm", "rec mm", "min at", "err mm", "CV min",
                "CV rec", "ratio", "m"):  # fmt: skip
        text = col in ("feed", "fault")
        table.add_column(col, justify="left" if text else "right", overflow="fold",
                         no_wrap=not text, min_width=widths.get(col, 6))  # fmt: skip
    for c in results["cases"]:
        a = c["advice"]
        table.add_row(str(c["case"]), c["feed"]["kind"], _short(c["leveller_fault"]),
                      f"{c['offset_mm']:+.1f}", f"{a['recommended_action_point_mm']:.1f}",
                      f"{c['brute_min_action_point_mm']:.1f}", f"{c['error_mm']:+.1f}",
                      f"{c['brute_min_cv_pct']:.3f}", f"{c['reached_cv_pct']:.3f}",
                      f"{c['cv_ratio']:.3f}", f"{a['metres_used']:.0f}")  # fmt: skip
    console.print(table)
    for group, s in results["summary"].items():
        console.print(f"{group}: within 5 mm {s['within_5_mm']} of {s['cases']}, CV within 5 % "
                      f"{s['within_5_pct_cv']} of {s['cases']}, both {s['both']}; median |error| "
                      f"{s['median_abs_error_mm']:.1f} mm, largest {s['max_abs_error_mm']:.1f} mm")  # fmt: skip
        heads = ", ".join(f"{k} {v[0]} of {v[1]}" for k, v in s["shorter_within_5_mm"].items())
        if heads:
            console.print(f"  from the records' first metres alone, within 5 mm: {heads}")
