"""How late 'plant serve' with the full physics publishes, idle and beside busy processes.

    python benchmarks/bench_plant_lag.py [--duration 60] [--busy 0,2] [--subscriber off,on]
                                         [--machines 1] [--src PATH] [--out plant_lag]

Per combination of ``--busy`` (that many processes spinning a core beside, started before and
killed after each run: the issue's "two busy neighbours"), ``--subscriber`` (``on``: an asyncua
client in its own process subscribed to every machine's ``sample`` node at a 10 ms publishing
interval, as ``twin run`` does) and ``--machines``, the command

    drafttwin plant serve --opcua URL --machines N --physics full --log plant.parquet

runs in its own process (not niced) for ``--duration`` seconds after it says it serves, then
gets SIGTERM. Figures: the samples its summary counts as late (published more than one sample
period after their time) and its max lag, the lag's p50/p99 from its log (``lag_s`` of every
sample), the seconds from SIGTERM to its exit, and the 1-min load average before and after.
``--src`` runs another checkout's code (e.g. ``--src ../main/src``: the figures before a
change). Prints one line per run and writes benchmarks/results/<out>.json (figure, unit,
machine, idle/busy); no figure is asserted.
"""

from __future__ import annotations

import argparse
import itertools
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

sys.path.insert(0, os.path.dirname(__file__))

from _machine import busy, write_results  # noqa: E402

SRC = Path(__file__).resolve().parents[1] / "src"
SUBSCRIBER = """
import asyncio, sys
from asyncua import Client

async def main(url, names):
    class H:
        def datachange_notification(self, node, val, data):
            pass
    while True:
        try:
            async with Client(url, timeout=2.0) as c:
                sub = await c.create_subscription(10.0, H())
                await sub.subscribe_data_change([c.get_node(f"ns=2;s={n}.sample") for n in names],
                                                queuesize=10000)
                while True:
                    await asyncio.sleep(1)
        except (OSError, asyncio.TimeoutError):
            await asyncio.sleep(0.1)

asyncio.run(main(sys.argv[1], sys.argv[2].split(",")))
"""
SUMMARY = re.compile(r"timing: (\d+) samples published late .*?max lag ([0-9.]+) s")


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def run_one(src: Path, machines: int, duration_s: float, subscriber: bool,
            busy_n: int) -> dict[str, Any]:  # fmt: skip
    url = f"opc.tcp://127.0.0.1:{_port()}"
    names = ["fa320a"] if machines == 1 else [f"fa320a-{k + 1}" for k in range(machines)]
    env = {**os.environ, "PYTHONPATH": str(src), "OMP_NUM_THREADS": "1"}
    load0 = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "plant.parquet"
        cmd = [sys.executable, "-c", "from drafttwin.cli import main; main()", "plant", "serve",
               "--opcua", url, "--machines", str(machines), "--physics", "full", "--log",
               str(log)]  # fmt: skip
        plant = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                 text=True)  # fmt: skip
        sub = None
        try:
            assert plant.stderr is not None
            line = plant.stderr.readline()
            if not line.startswith("serving"):
                raise RuntimeError(f"plant serve did not start: {line}{plant.stderr.read()}")
            if subscriber:
                sub = subprocess.Popen([sys.executable, "-c", SUBSCRIBER, url, ",".join(names)],
                                       env=env, stderr=subprocess.DEVNULL)  # fmt: skip
            time.sleep(duration_s)
            t_term = time.monotonic()
            plant.send_signal(signal.SIGTERM)
            out, err = plant.communicate(timeout=60)
            stop_s = time.monotonic() - t_term
        finally:
            for p in (sub, plant):
                if p is not None and p.poll() is None:
                    p.kill()
                    p.wait()
        found = SUMMARY.search(out)
        if found is None:
            raise RuntimeError(f"no timing summary:\n{out}\n{err}")
        lag = pd.read_parquet(log)["lag_s"].to_numpy() if log.exists() else np.array([])
    q = np.quantile(lag, [0.5, 0.99]) if len(lag) else [float("nan")] * 2
    return {"figure": "samples published late (> 1 sample period) and their lag",
            "unit": "samples, s", "load": f"busy {busy_n}" if busy_n else "idle",
            "busy": busy_n, "subscriber": subscriber, "machines": machines, "physics": "full",
            "src": str(src), "duration_s": duration_s, "published": int(len(lag)),
            "late": int(found.group(1)), "max_lag_s": float(found.group(2)),
            "lag_p50_s": float(q[0]), "lag_p99_s": float(q[1]),
            "sigterm_to_exit_s": round(stop_s, 2), "traceback": "Traceback" in err,
            "warnings": [x for x in err.splitlines() if x.startswith("warning")],
            "load_average_1min_before": round(load0, 2),
            "load_average_1min_after": round(os.getloadavg()[0], 2)}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0, help="seconds served per run")
    ap.add_argument("--busy", default="0,2", help="comma-separated, e.g. 0,2")
    ap.add_argument("--subscriber", default="off,on", help="comma-separated: off, on")
    ap.add_argument("--machines", default="1", help="comma-separated, e.g. 1,2")
    ap.add_argument("--src", type=Path, default=SRC, help="the drafttwin source tree to run")
    ap.add_argument("--out", default="plant_lag")
    a = ap.parse_args()
    figures = []
    cases = list(itertools.product(map(int, a.machines.split(",")), a.subscriber.split(",")))
    for busy_n in map(int, a.busy.split(",")):
        with busy(busy_n):
            for machines, sub in cases:
                f = run_one(a.src.resolve(), machines, a.duration, sub == "on", busy_n)
                figures.append(f)
                print(f"{f['load']:>6}, {machines} machine(s), subscriber {sub:>3}: "
                      f"{f['late']} of {f['published']} samples late, max lag "
                      f"{f['max_lag_s']:.3f} s, p50 {f['lag_p50_s'] * 1e3:.1f} ms, p99 "
                      f"{f['lag_p99_s'] * 1e3:.1f} ms, SIGTERM to exit "
                      f"{f['sigterm_to_exit_s']:.1f} s, load "
                      f"{f['load_average_1min_before']:.1f}-{f['load_average_1min_after']:.1f}",
                      flush=True)  # fmt: skip
    print(f"wrote {write_results(a.out, figures)}")


if __name__ == "__main__":
    main()
