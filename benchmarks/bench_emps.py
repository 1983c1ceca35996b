"""Wall times of the EMPS benchmark's pieces (CPU, quick profile, seed 0).

    python benchmarks/bench_emps.py [--data-dir DIR] [--repeat 3]

Needs the EMPS data (see docs/emps.md). Prints a table and writes benchmarks/results/emps.json.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable
from typing import Any

sys.path.insert(0, os.path.dirname(__file__))

from _machine import write_results  # noqa: E402
from drafttwin.datasets.emps import load_emps  # noqa: E402
from drafttwin.models import make_model  # noqa: E402
from drafttwin.studies.emps.physics import EmpsPhysics, rmse_mm  # noqa: E402
from drafttwin.studies.emps.plan import EmpsConfig, hyperparameters  # noqa: E402


def best_of(fn: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    """Shortest wall time of ``repeat`` calls (s) and the last result."""
    walls, out = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        out = fn()
        walls.append(time.perf_counter() - start)
    return min(walls), out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--data-dir", default=None)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    figures: list[dict[str, Any]] = []

    def add(name: str, value: float, unit: str) -> None:
        figures.append({"figure": name, "value": value, "unit": unit})
        print(f"{name:<62} {value:>10.3f} {unit}")

    wall, (train, test, _) = best_of(lambda: load_emps(args.data_dir), args.repeat)
    add("load + SHA-256 check of both records", wall, "s")
    physics = EmpsPhysics()
    physics.simulate(test.vir_v[:10], 0.0)  # compile or load the numba cache
    wall, pred = best_of(lambda: physics.simulate(test.vir_v, test.qm_m[0]), args.repeat)
    add("physics open-loop run, test record (24.84 s, RK4 1e-4 s)", wall, "s")
    add("physics test RMSE (check)", rmse_mm(test.qm_m, pred, 20), "mm")
    config = EmpsConfig(profile="quick", device="cpu")
    mech = physics.mechanistic()
    for name in ("parallel", "gru", "md-s-l"):
        model = make_model(name, "quick", **hyperparameters(name, "simulation", config, 0))
        start = time.perf_counter()
        model.fit(train.series(), mech)
        add(f"fit {name}, simulation mode, quick profile", time.perf_counter() - start, "s")
        start = time.perf_counter()
        model.predict_values(test.series(), mech)
        wall = time.perf_counter() - start
        add(f"free run of {name} over the test record", wall, "s")
        if name == "gru":
            add("NARX GRU free-run step (2 x 48, window 20)", wall / (len(test) - 20) * 1e3, "ms")
    print(f"wrote {write_results('emps', figures)}")


if __name__ == "__main__":
    main()
