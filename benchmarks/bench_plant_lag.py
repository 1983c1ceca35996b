"""How late 'plant serve' publishes, and what it does about it, on this machine.

    python benchmarks/bench_plant_lag.py [--machines 2] [--duration 30] [--physics full]
                                         [--max-lag none,1]

Per ``--max-lag`` value (``none``: publish every sample, the default; a number: skip samples
once that many seconds behind) the plant is served over OPC UA in-process for ``--duration``
seconds of samples; each published sample's lag (wall clock when it went out minus its source
time) is collected. Prints a table and writes benchmarks/results/plant_lag.json: samples
published and skipped per machine, the lag's quantiles, the warnings and the wall time taken.
Run it beside busy processes (e.g. two ``yes > /dev/null``) to see the lateness said.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import os
import socket
import sys
import time
from typing import Any

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))

from _machine import write_results  # noqa: E402
from drafttwin.plant.serve.opcua import serve_opcua  # noqa: E402
from drafttwin.plant.serve.pacing import Pacing  # noqa: E402


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def run_one(machines: int, duration_s: float, physics: str, max_lag: float) -> dict[str, Any]:
    lags: list[float] = []
    warned: list[str] = []
    pacing = Pacing(100.0, max_lag_s=max_lag, warn=warned.append)
    names = [f"m{k + 1}" for k in range(machines)]

    def on_sample(name: str, s: Any) -> None:
        lags.append(time.time() - s.time_s)

    start = time.monotonic()
    last = asyncio.run(serve_opcua(f"opc.tcp://127.0.0.1:{_port()}", names, physics=physics,
                                   duration_s=duration_s, on_sample=on_sample, pacing=pacing))  # fmt: skip
    wall = time.monotonic() - start
    q = np.quantile(lags, [0.5, 0.9, 0.99, 1.0]) if lags else [math.nan] * 4
    return {"machines": machines, "physics": physics, "duration_s": duration_s,
            "max_lag_s": None if math.isinf(max_lag) else max_lag,
            "published_per_machine": len(lags) // machines, "last_seq": max(last.values()),
            "skipped": pacing.skipped, "warnings": pacing.warnings,
            "physics_bound": pacing.physics_bound,
            "lag_p50_s": float(q[0]), "lag_p90_s": float(q[1]), "lag_p99_s": float(q[2]),
            "lag_max_s": float(q[3]), "wall_s_incl_startup": wall,
            "load_average_1min": os.getloadavg()[0]}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--machines", type=int, default=2)
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--physics", default="full", choices=("full", "reduced"))
    ap.add_argument("--max-lag", default="none,1")
    args = ap.parse_args()
    figures = []
    for text in args.max_lag.split(","):
        max_lag = math.inf if text == "none" else float(text)
        fig = run_one(args.machines, args.duration, args.physics, max_lag)
        figures.append(fig)
        print(f"max-lag {text:>5}: published {fig['published_per_machine']}/machine, skipped "
              f"{fig['skipped']}, lag p50 {fig['lag_p50_s']:.3f} p99 {fig['lag_p99_s']:.3f} max "
              f"{fig['lag_max_s']:.3f} s, {fig['warnings']} warnings, load "
              f"{fig['load_average_1min']:.1f}")  # fmt: skip
    print(f"wrote {write_results('plant_lag', figures)}")


if __name__ == "__main__":
    main()
