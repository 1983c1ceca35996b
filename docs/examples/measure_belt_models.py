"""A machine that is not the FA320A, end to end: the tutorial's belt drive (docs/own-machine.md).

    python docs/examples/measure_belt_models.py [--seeds 3] [--epochs N]   # from the repository root

The belt-drive records of ``docs/examples/make_belt_records.py`` (seed 0: two training
records of 40 s, a test record of 30 s, 50 Hz, output ``y`` in rad/s, input ``u`` in V); the
physics is the drawing's drive train (``docs/examples/belt_drive.toml``), once simulated
directly and once read back as a simulator output file. Every model is fitted on both training
records with the quick profile (its full budget unless ``--epochs``) and scored by the
evaluation protocol on the separate test record in free-run simulation from 20 measured
samples. Prints a table and writes benchmarks/results/own_machine.json (RMSE in rad/s, wall
times in s) below the folder it is run from. A study of the tutorial's data, so it lives beside
the tutorial, not among the timing scripts of ``benchmarks/``.
"""

from __future__ import annotations

import argparse
import importlib.util
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

import drafttwin as dt
from drafttwin.studies.figures import write_results

EXAMPLES = Path(__file__).resolve().parent
CHANNELS = {"outputs": ["y"], "inputs": ["u"], "units": {"y": "rad/s", "u": "V"}}


def records(folder: Path) -> tuple[dt.MeasurementSeries, dt.MeasurementSeries]:
    spec = importlib.util.spec_from_file_location("belt", EXAMPLES / "make_belt_records.py")
    assert spec is not None and spec.loader is not None
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    rng = np.random.default_rng(0)  # as `make_belt_records.py OUT --seed 0`
    parts = [gen.record(40.0, rng).assign(record=k) for k in (1, 2)]
    pd.concat(parts, ignore_index=True).to_csv(folder / "train.csv", index=False)
    gen.record(30.0, rng).to_csv(folder / "test.csv", index=False)
    return (dt.read_measurements(folder / "train.csv", **CHANNELS),
            dt.read_measurements(folder / "test.csv", **CHANNELS))  # fmt: skip


def run(name: str, seed: int, train, test, physics, epochs: int | None) -> dict[str, Any]:
    options: dict[str, Any] = {"task": "simulation", "init_samples": 20}
    if name not in ("mechanistic", "persistence"):
        options |= {"inputs": ["u"], "seed": seed, "quiet": True, "device": "cpu"}
        if epochs is not None:
            options["epochs"] = epochs
    model = dt.make_model(name, "quick", **options)
    start = time.perf_counter()
    part = dt.fit_split(model, train, test=test, mechanistic=physics)
    fit_s = time.perf_counter() - start
    result = dt.evaluate(model, part, mechanistic=physics)
    choice = model.selection_.get("accumulate", {})
    return {"model": name, "seed": seed, "rmse": result.metrics["y"].rmse,
            "skill": result.metrics["y"].skill, "fit_s": fit_s,
            "accumulate": choice.get("accumulate")}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--epochs", type=int, default=None)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        train, test = records(Path(tmp))
        physics = dt.MechanisticModel.from_config(EXAMPLES / "belt_drive.toml")
        runs = [
            run(m, 0, train, test, physics, args.epochs) for m in ("mechanistic", "persistence")
        ]
        for name in ("gru", "parallel", "md-s-l"):
            runs += [run(name, s, train, test, physics, args.epochs) for s in range(args.seeds)]
    figures: list[dict[str, Any]] = []
    budget = "quick profile" + (f", {args.epochs} epochs" if args.epochs else "")
    print(f"{'model':<12} {'RMSE rad/s (mean, min-max over seeds)':<40} {'fit s':>7}  accumulate")
    for name in ("mechanistic", "persistence", "gru", "parallel", "md-s-l"):
        rows = [r for r in runs if r["model"] == name]
        rmse = np.array([r["rmse"] for r in rows])
        fit_s = float(np.mean([r["fit_s"] for r in rows]))
        acc = sorted({str(r["accumulate"]) for r in rows})
        print(f"{name:<12} {rmse.mean():.4f} ({rmse.min():.4f}-{rmse.max():.4f}){'':<18} "
              f"{fit_s:>7.1f}  {','.join(acc)}")  # fmt: skip
        figures.append({"figure": f"{name} free-run RMSE on the test record ({budget})",
                        "value": float(rmse.mean()), "unit": "rad/s",
                        "runs": [float(x) for x in rmse]})  # fmt: skip
        figures.append({"figure": f"{name} fit wall time", "value": fit_s, "unit": "s"})
    print(f"wrote {write_results('own_machine', figures)}")


if __name__ == "__main__":
    main()
