"""Run the fault benchmark: plan, plant records in parallel, scores."""

from __future__ import annotations

import resource
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from drafttwin._constants import __version__
from drafttwin.errors import unknown_choice
from drafttwin.execution.executor import run_tasks
from drafttwin.studies.faults.plan import PLANS, BenchmarkPlan, run_record, task_configs
from drafttwin.studies.faults.score import score_records


def get_plan(name: str) -> BenchmarkPlan:
    try:
        return PLANS[name]
    except KeyError:
        raise unknown_choice(f"unknown benchmark plan '{name}'", PLANS, where="--quick") from None


def _cpu() -> float:
    """CPU seconds of this process and of its waited-for children so far."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def run_benchmark(plan: BenchmarkPlan | str = "full", seed: int = 0, workers: int = 1,
                  on_record: Callable[[int, int], None] | None = None,
                  on_stage: Callable[[str], None] | None = None,
                  records: Path | None = None) -> dict[str, Any]:  # fmt: skip
    """Results of one benchmark run (JSON-able): plan, scores per method, every record.
    ``records``: the folder its plant records are kept in (:mod:`.records`): made once,
    read back by later runs (and served by the live benchmark)."""
    plan = get_plan(plan) if isinstance(plan, str) else plan
    tasks = task_configs(plan, seed)
    if records is not None:
        tasks = [{**t, "_records": str(records)} for t in tasks]
    start = time.perf_counter()
    done = [0]

    def progress(i: int, result: dict[str, Any], cached: bool) -> None:
        done[0] += 1
        if on_record is not None:
            on_record(done[0], len(tasks))

    cpu0 = _cpu()
    results = run_tasks(run_record, tasks, workers=workers, on_result=progress)
    plant_s, cpu1 = time.perf_counter() - start, _cpu()
    if on_stage is not None:
        on_stage("fitting the networks on the tuning set, scoring")
    scored = score_records(tasks, results, seed=seed)
    cpu2 = _cpu()
    return {
        "benchmark": "faults", "drafttwin_version": __version__, "plan": plan.name,
        "seed": seed, "workers": workers, "wall_s": time.perf_counter() - start,
        "plant_wall_s": plant_s,
        # CPU time (this process and its finished workers): on a shared machine the wall time
        # says little; the plant part runs in parallel, the scoring in this process alone
        "cpu_s": {"plant": cpu1 - cpu0, "scoring": cpu2 - cpu1},
        "sets": {s: sum(t["set"] == s for t in tasks) for s in ("tuning", "faults", "healthy")},
        "machine_seconds": {s: sum(t["duration_s"] for t in tasks if t["set"] == s)
                            for s in ("tuning", "faults", "healthy")},
        **scored,
    }  # fmt: skip
