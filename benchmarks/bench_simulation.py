"""Wall time of the FA320A simulation (numba RK4) at 1 kHz output, after compilation.

    python benchmarks/bench_simulation.py [--repeat 3]

Prints a table and writes benchmarks/results/simulation.json.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(__file__))

from _machine import write_results  # noqa: E402
from drafttwin.mechanics import DriveTrain, simulate  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    train = DriveTrain.preset("fa320a")
    t0 = time.perf_counter()
    simulate(train, 0.01, settle_s=0.0)  # compile or load the numba cache
    first_call = time.perf_counter() - t0
    figures = [{"figure": "first call (compile or cache load)", "value": first_call, "unit": "s"}]
    print(f"first call (compile / cache load): {first_call:.2f} s")
    print(f"{'machine time':>14} {'dt':>9} {'best wall':>10} {'real-time factor':>17}")
    for dt in (train.spec.solver.dt_s, 1e-5):
        for duration in (10.0, 60.0):
            walls = [simulate(train, duration, output_rate_hz=1000.0, dt_s=dt, settle_s=0.0).wall_s
                     for _ in range(args.repeat if duration < 30 else 1)]  # fmt: skip
            best = min(walls)
            print(f"{duration:>12.0f} s {dt:>9.0e} {best:>9.2f}s {duration / best:>16.1f}x")
            figures.append({"figure": f"simulate {duration:.0f} s fa320a, 1 kHz, dt {dt:.0e} s",
                            "value": best, "unit": "s wall"})  # fmt: skip
            figures.append({"figure": f"real-time factor {duration:.0f} s, dt {dt:.0e} s",
                            "value": duration / best, "unit": "x"})  # fmt: skip
    print(f"wrote {write_results('simulation', figures)}")


if __name__ == "__main__":
    main()
