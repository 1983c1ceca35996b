"""Wall time of ``drafttwin reproduce --profile quick`` and where the time goes.

    python benchmarks/bench_study.py [--workers N]

Runs the study into a temporary folder (no cache), prints the stage times and writes
benchmarks/results/study.json.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, os.path.dirname(__file__))

from _machine import write_results  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--profile", default="quick")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        cmd = ["drafttwin", "reproduce", "--profile", args.profile, "--out", tmp, "--quiet"]
        if args.workers:
            cmd += ["--workers", str(args.workers)]
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True)
        wall = time.perf_counter() - t0
        results = json.loads((Path(tmp) / "results.json").read_text())
    stages = results["timings"]["stages"]
    print(f"reproduce --profile {args.profile}: {wall:.0f} s wall (process included)")
    figures = [{"figure": f"reproduce --profile {args.profile}, wall", "value": wall, "unit": "s"}]
    for name, secs in stages.items():
        print(f"  {name:12s} {secs:7.1f} s")
        figures.append({"figure": f"stage {name}", "value": secs, "unit": "s"})
    fits = sorted(results["timings"]["fits"], key=lambda f: -(f["wall_s"] or 0))
    for f in fits[:5]:
        print(f"  slowest fit: {f['task']:40s} {f['wall_s']:.1f} s")
    fit_total = sum(f["wall_s"] or 0 for f in fits)
    figures.append(
        {"figure": "sum of fit wall times (parallel workers)", "value": fit_total, "unit": "s"}
    )
    print(f"wrote {write_results('study', figures)}")


if __name__ == "__main__":
    main()
