"""How long a fit takes from the CLI, on an idle machine and beside two busy processes.

Cases (each a ``drafttwin fit`` subprocess, as a user runs it):

* ``parallel-default``: ``fit --model parallel --data default`` (target of issue 38: <= 25 s
  idle, busy <= 1.5x idle);
* ``mdsl-1000``: MD-S-L on a 1000-row one-channel record (one input, a simulator file as the
  physics; made here, seed 3) with the default profile (target <= 30 CPU-s);
* ``mdsl-1000-standard``: the same with ``--profile standard`` (target: usable, <= 5 min).

Each case runs idle and then with two busy processes (``while True: pass``) beside it; with
``--cores 0,1`` the fit and the busy processes are pinned to those cores (``taskset``), which
makes a many-core machine behave like the 2-core one the targets are set for. Wall seconds and
CPU seconds (user + system of the fit's process tree) are reported, with the busy/idle ratio.

Prints a table and writes ``benchmarks/results/fit.json``. Run:
``python benchmarks/bench_fit.py [--cases parallel-default,mdsl-1000] [--cores 0,1]
[--threads N]`` (``--threads`` sets DRAFTTWIN_THREADS for the fits).
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import write_results  # noqa: E402

ROWS = 1000
DT_S = 0.01


def one_channel_record(folder: Path, seed: int = 3) -> tuple[Path, Path]:
    """A 1000-row record (t, u, y) of a second-order drive with smooth Coulomb friction, and
    a simulator file of its linear part (the physics without the friction)."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(-1.0, 1.0, ROWS // 50 + 1), 50)[:ROWS]

    def simulate(friction: float) -> np.ndarray:
        x, v, y = 0.0, 0.0, np.zeros(ROWS)
        for k in range(ROWS):
            y[k] = x
            a = 4.0 * u[k] - 2.0 * v - 8.0 * x - friction * 0.3 * np.tanh(5.0 * v)
            x, v = x + DT_S * v, v + DT_S * a
        return y

    t = np.arange(ROWS) * DT_S
    record, physics = folder / "record.csv", folder / "physics.csv"
    y = simulate(1.0) + rng.normal(0.0, 0.002, ROWS)
    pd.DataFrame({"t": t, "u": u, "y": y}).to_csv(record, index=False)
    pd.DataFrame({"t": t, "y": simulate(0.0)}).to_csv(physics, index=False)
    return record, physics


def case_args(name: str, folder: Path) -> list[str]:
    out = ["--out", str(folder / f"{name}.dtm"), "--quiet"]
    if name == "parallel-default":
        return ["fit", "--model", "parallel", "--data", "default", *out]
    record, physics = one_channel_record(folder)
    args = ["fit", "--model", "md-s-l", "--data", str(record), "--outputs", "y", "--inputs",
            "u", "--units", "y=m,u=V", "--time-column", "t", "--mechanistic", str(physics), *out]  # fmt: skip
    return args + (["--profile", "standard"] if name.endswith("standard") else [])


def pinned(cores: str | None, argv: list[str]) -> list[str]:
    return argv if cores is None else ["taskset", "-c", cores, *argv]


def run_fit(args: list[str], cores: str | None, env: dict[str, str]) -> dict[str, float]:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    argv = [sys.executable, "-c", "from drafttwin.cli import main; main()", *args]
    done = subprocess.run(pinned(cores, argv), env=env, capture_output=True, text=True,
                          check=False, timeout=3600)  # fmt: skip
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"fit failed ({done.returncode}): {done.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall_s": wall, "cpu_s": cpu}


def busy_processes(cores: str | None, n: int = 2) -> list[subprocess.Popen[bytes]]:
    spin = [
        sys.executable,
        "-c",
        "import time\nend = time.time() + 7200\nwhile time.time() < end: pass",
    ]
    return [subprocess.Popen(pinned(cores, spin)) for _ in range(n)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", default="parallel-default,mdsl-1000,mdsl-1000-standard")
    parser.add_argument("--cores", default=None, help="pin fits and busy processes, e.g. 0,1")
    parser.add_argument("--threads", type=int, default=None, help="DRAFTTWIN_THREADS")
    parser.add_argument("--only", choices=["idle", "busy", "both"], default="both")
    opts = parser.parse_args()
    env = dict(os.environ)
    if opts.threads is not None:
        env["DRAFTTWIN_THREADS"] = str(opts.threads)
    figures: list[dict[str, Any]] = []
    modes = ["idle", "busy"] if opts.only == "both" else [opts.only]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for name in opts.cases.split(","):
            args = case_args(name, folder)
            seen: dict[str, dict[str, float]] = {}
            for mode in modes:
                spinners = busy_processes(opts.cores) if mode == "busy" else []
                try:
                    seen[mode] = run_fit(args, opts.cores, env)
                finally:
                    for p in spinners:
                        p.kill()
                        p.wait()
                r = seen[mode]
                print(f"{name:20s} {mode:4s} wall {r['wall_s']:7.1f} s  cpu {r['cpu_s']:7.1f} s",
                      flush=True)  # fmt: skip
                for key, unit in (("wall_s", "s"), ("cpu_s", "CPU-s")):
                    figures.append({"figure": f"{name} {key[:-2]}", "value": round(r[key], 2),
                                    "unit": unit, "load": mode, "cores": opts.cores or "all",
                                    "threads": env.get("DRAFTTWIN_THREADS", "default")})  # fmt: skip
            if len(seen) == 2:
                ratio = seen["busy"]["wall_s"] / seen["idle"]["wall_s"]
                print(f"{name:20s} busy/idle wall ratio {ratio:.2f}")
                figures.append({"figure": f"{name} busy/idle wall", "value": round(ratio, 2),
                                "unit": "ratio", "load": "both", "cores": opts.cores or "all"})  # fmt: skip
    print(f"wrote {write_results('fit', figures)}")


if __name__ == "__main__":
    main()
