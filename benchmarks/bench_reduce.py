"""The reduced FA320A drive train against the full one: wall time and error.

    python benchmarks/bench_reduce.py [--repeat 5] [--cutoff-hz 200]

Wall time of 10 s of machine time at 1 kHz output (after compilation, one core), full model at
its configured step vs the reduced model at its own step; and the reduced model's error
against the full model on a start-up from rest (VFD ramp to 48.47 Hz in 3 s), the steady run
and a speed change (48.47 -> 40 Hz in 0.5 s): RMSE of 0.1 s block means per roller, in % of
the roller's steady speed. Prints a table and writes benchmarks/results/reduce.json.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))

from _machine import write_results  # noqa: E402
from drafttwin._constants import ROLLERS  # noqa: E402
from drafttwin.mechanics import DEFAULT_CUTOFF_HZ, DriveTrain, Signal, reduce, simulate  # noqa: E402

RATE = 1000.0
BLOCK = 100  # samples per 0.1 s block
# start-up (0-5 s), steady (5-6 s), speed change and settling (6-10 s)
SCHEDULE = Signal.from_samples([0.0, 3.0, 6.0, 6.5, 10.0], [0.0, 48.47, 48.47, 40.0, 40.0], 1e-2)
PHASES = {"start-up 0-5 s": slice(0, 50), "steady 5-6 s": slice(50, 60),
          "speed change 6-10 s": slice(60, 100)}  # fmt: skip


def _blocks(x: np.ndarray) -> np.ndarray:
    return x[: len(x) // BLOCK * BLOCK].reshape(-1, BLOCK, x.shape[1]).mean(axis=1)


def _best_wall(train: DriveTrain, repeat: int) -> tuple[float, float]:
    runs = [simulate(train, 10.0, output_rate_hz=RATE, settle_s=0.0) for _ in range(repeat)]
    return min(r.wall_s for r in runs), runs[0].dt_s


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--cutoff-hz", type=float, default=DEFAULT_CUTOFF_HZ)
    args = parser.parse_args()
    train = DriveTrain.preset("fa320a")
    t0 = time.perf_counter()
    small = reduce(train, args.cutoff_hz)
    reduce_ms = (time.perf_counter() - t0) * 1e3
    assert small.reduction is not None
    print(small.reduction.summary())
    simulate(small, 0.01, settle_s=0.0)  # compile or load the numba caches
    simulate(train, 0.01, settle_s=0.0)
    full_wall, full_dt = _best_wall(train, max(1, args.repeat // 2))
    red_wall, red_dt = _best_wall(small, args.repeat)
    figures = [
        {"figure": "reduce() (first call, incl. modal analysis)", "value": reduce_ms, "unit": "ms"},
        {"figure": f"full model, 10 s machine time, dt {full_dt:.0e} s", "value": full_wall,
         "unit": "s wall"},
        {"figure": f"reduced model, 10 s machine time, dt {red_dt:.0e} s, cut-off "
         f"{args.cutoff_hz:g} Hz", "value": red_wall, "unit": "s wall"},
        {"figure": "speed-up reduced vs full", "value": full_wall / red_wall, "unit": "x"},
        {"figure": "highest remaining eigenfrequency", "value": small.reduction.highest_hz,
         "unit": "Hz"},
    ]  # fmt: skip
    print(f"10 s machine time: full {full_wall:.3f} s (dt {full_dt:.0e}), reduced "
          f"{red_wall:.4f} s (dt {red_dt:.0e}), {full_wall / red_wall:.0f}x")  # fmt: skip
    driven = train.with_supply_schedule(SCHEDULE)
    full = simulate(driven, 10.0, output_rate_hz=RATE, from_rest=True, settle_s=0.0)
    red = simulate(reduce(driven, args.cutoff_hz), 10.0, output_rate_hz=RATE, from_rest=True,
                   settle_s=0.0)  # fmt: skip
    steady = full.roller_rpm()[5500:6000].mean(axis=0)
    err = _blocks(red.roller_rpm()) - _blocks(full.roller_rpm())
    print(f"{'RMSE of 0.1 s block means, % of steady':<40}" + "".join(f"{r:>10}" for r in ROLLERS))
    for phase, rows in PHASES.items():
        rmse = 100 * np.sqrt((err[rows] ** 2).mean(axis=0)) / steady
        print(f"{phase:<40}" + "".join(f"{v:>10.5f}" for v in rmse))
        figures += [{"figure": f"reduced vs full, {phase}, {r} roller, RMSE of 0.1 s block means",
                     "value": float(v), "unit": "% of steady speed"}
                    for r, v in zip(ROLLERS, rmse, strict=True)]  # fmt: skip
    worst = 100 * np.abs(err).max(axis=0) / steady
    print(f"{'largest block error':<40}" + "".join(f"{v:>10.5f}" for v in worst))
    figures += [{"figure": f"reduced vs full, largest 0.1 s block error, {r} roller",
                 "value": float(v), "unit": "% of steady speed"}
                for r, v in zip(ROLLERS, worst, strict=True)]  # fmt: skip
    print(f"wrote {write_results('reduce', figures)}")


if __name__ == "__main__":
    main()
