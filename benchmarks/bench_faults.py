"""Cost of fault injection in the plant and of diagnosing a record.

    python benchmarks/bench_faults.py [--duration 30]

Wall and CPU time of the plant (100 Hz, one core, numba caches loaded) for ``--duration`` s
of machine time: healthy, with an abrupt bearing fault, with a ramping one (new tables every
0.25-s block) and with a gear crack (the kernel's crack branch), with the CPU seconds per
machine second that size `benchmark faults`; the time to diagnose one record (physics
residual features, detection, localisation, spectral evidence); and the benchmark's learned
residuals (the one-step GRU and the parallel hybrid): one fit on the healthy record and the
prediction of one record. CPU time is the figure to trust on a shared machine. Prints a
table and writes benchmarks/results/faults.json.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(__file__))

from _machine import write_results  # noqa: E402
from drafttwin.diagnosis.detect import FaultDetector  # noqa: E402
from drafttwin.diagnosis.diagnose import Diagnoser  # noqa: E402
from drafttwin.diagnosis.residuals import physics_prediction, record_features  # noqa: E402
from drafttwin.mechanics import DriveTrain  # noqa: E402
from drafttwin.plant import Plant  # noqa: E402
from drafttwin.plant.faults import FaultSpec  # noqa: E402
from drafttwin.studies.faults.learned import LEARNED, LearnedResiduals, raw_record  # noqa: E402

CASES = {
    "healthy": [],
    "bearing step": ["front_roller:bearing_friction:severity=5:onset=20"],
    "bearing ramp": ["front_roller:bearing_friction:severity=5:onset=2:ramp=15"],
    "gear crack": ["G-H:crack:severity=0.5:onset=5"],
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--duration", type=float, default=30.0)
    args = parser.parse_args()
    plant, train = Plant(), DriveTrain.preset("fa320a")
    plant.run(0.5, seed=0)  # load the numba caches
    figures, recs = [], {}
    for name, faults in CASES.items():
        t0, c0 = time.perf_counter(), time.process_time()
        recs[name] = plant.run(args.duration, seed=1, faults=[FaultSpec.parse(f) for f in faults])
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        figures += [{"figure": f"plant, {args.duration:g} s at 100 Hz, {name}",
                     "value": wall, "unit": "s wall"},
                    {"figure": f"plant CPU per machine second, {name}",
                     "value": cpu / args.duration, "unit": "CPU-s per s"}]  # fmt: skip
        print(f"plant {name:<14} {wall:7.2f} s wall, {cpu / args.duration:.3f} CPU-s per s")
    det = FaultDetector().fit([record_features(train, recs["healthy"].series)])
    dx = Diagnoser(train, det)
    t0 = time.perf_counter()
    out = dx.diagnose(recs["bearing step"].series)
    wall = time.perf_counter() - t0
    figures.append({"figure": f"diagnose one {args.duration:g}-s record (alarm and ranking)",
                    "value": wall, "unit": "s wall"})  # fmt: skip
    print(f"diagnose: {wall:.2f} s, alarm {out.alarm}")
    raws = {k: raw_record(r.series, physics_prediction(train, r.series)) for k, r in recs.items()}
    c0 = time.process_time()
    learned = LearnedResiduals(1.0).fit([raws["healthy"]])
    cpu = time.process_time() - c0
    figures.append({"figure": f"learned residuals: fit both networks on one {args.duration:g}-s "
                    "record", "value": cpu, "unit": "CPU-s"})  # fmt: skip
    print(f"learned fit: {cpu:.2f} CPU-s ({learned.fit_s_})")
    for method in LEARNED:
        c0 = time.process_time()
        learned.features(method, raws["bearing step"])
        cpu = time.process_time() - c0
        figures.append({"figure": f"{method} residual features of one {args.duration:g}-s record",
                        "value": cpu, "unit": "CPU-s"})  # fmt: skip
        print(f"{method} features: {cpu:.3f} CPU-s")
    print("wrote", write_results("faults", figures))


if __name__ == "__main__":
    main()
