"""Do viewers slow the twin? A served plant, ``twin run`` with its page and store, and N HTTP
clients asking for history as fast as they are answered.

    python benchmarks/bench_twin_viewers.py [--clients 100] [--seconds 60] [--busy 0]
                                            [--path "/api/history/fa320a?seconds=60"]

One machine at 100 Hz (``plant serve --physics reduced`` over OPC UA) feeds ``twin run --http
--store --verbose``; the twin prints a line per store commit (rows, its last sample's time), so
its processing rate and data age (the wall clock at the commit minus the newest sample's
source time, which the plant stamps on the wall clock) are read from the twin itself, with no
extra request. Three phases of ``--seconds`` each: idle, N clients (each sends the next request
when the last is answered; a 429 waits its Retry-After, unless ``--rude``), idle again. Prints rows/s, data age
p50/p99/max per phase and the clients' answers (count per status, latency p50/p99), and writes
benchmarks/results/twin_viewers.json. The clients run in this process (asyncio, keep-alive
HTTP/1.1), on the same cores as the twin: as on a small box where browsers and twin meet.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))

from _machine import write_results  # noqa: E402
from bench_stop import Proc, Setup, busy, cli, free_port  # noqa: E402


class Commits:
    """The twin's commit lines: (wall time, rows, newest sample's time)."""

    def __init__(self, proc: Proc) -> None:
        self.rows: list[tuple[float, int, float]] = []
        self._n = 0
        self.proc = proc

    def poll(self) -> None:
        lines = self.proc.out
        while self._n < len(lines):
            line = lines[self._n]
            self._n += 1
            if line.startswith("commit "):
                f = dict(p.split("=", 1) for p in line.split()[1:])
                self.rows.append((float(f["at"]), int(f["rows"]), int(f["last_ts_us"]) / 1e6))

    def follow(self, stop: threading.Event) -> None:
        while not stop.wait(0.5):
            self.poll()

    def phase(self, t0: float, t1: float) -> dict:
        self.poll()
        got = [(at, n, last) for at, n, last in self.rows if t0 <= at < t1]
        if not got:
            return {"rows_per_s": 0.0, "data_age_s": None}
        age = np.array([at - last for at, _, last in got])
        return {"rows_per_s": sum(n for _, n, _ in got) / (t1 - t0),
                "data_age_s": {"p50": float(np.percentile(age, 50)),
                               "p99": float(np.percentile(age, 99)), "max": float(age.max())}}  # fmt: skip


async def _client(port: int, path: str, until: float, out: dict, rude: bool) -> None:
    """Requests on one keep-alive connection until ``until``; statuses and latencies kept."""
    reader = writer = None
    while time.monotonic() < until:
        try:
            if writer is None:
                reader, writer = await asyncio.open_connection("127.0.0.1", port)
            assert reader is not None
            t0 = time.monotonic()
            writer.write(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), 30)
            lines = head.decode("latin-1").split("\r\n")
            code = int(lines[0].split()[1])
            fields = {
                k.lower(): v.strip() for k, _, v in (x.partition(":") for x in lines[1:] if x)
            }
            await asyncio.wait_for(reader.readexactly(int(fields.get("content-length", 0))), 30)
            out.setdefault(code, []).append(time.monotonic() - t0)
            if code == 429 and not rude:
                await asyncio.sleep(float(fields.get("retry-after", 1)))
            if fields.get("connection", "").lower() == "close":
                writer.close()
                writer = None
        except (TimeoutError, OSError, asyncio.IncompleteReadError, ValueError):
            out.setdefault("error", []).append(0.0)
            if writer is not None:
                writer.close()
            writer = None
            await asyncio.sleep(0.1)
    if writer is not None:
        writer.close()


async def _load(port: int, path: str, clients: int, seconds: float, rude: bool) -> dict:
    out: dict = {}
    until = time.monotonic() + seconds
    await asyncio.gather(*(_client(port, path, until, out, rude) for _ in range(clients)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--clients", type=int, default=100)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--warmup", type=float, default=20.0)
    ap.add_argument("--busy", type=int, default=0)
    ap.add_argument("--path", default="/api/history/fa320a?seconds=60")
    ap.add_argument("--rude", action="store_true", help="clients ignore Retry-After")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-viewers-") as tmp:
        setup = Setup(Path(tmp))
        print("making a record and a tiny model ...", flush=True)
        setup.make()
        url, http = f"opc.tcp://127.0.0.1:{free_port()}", free_port()
        plant = Proc(cli("plant", "serve", "--opcua", url, "--physics", "reduced"))
        twin = None
        try:
            plant.wait_for("serving", 90)
            twin = Proc(cli("twin", "run", "--model", str(setup.model), "--source", f"opcua:{url}",
                            "--http", f"127.0.0.1:{http}", "--store", str(Path(tmp) / "store"),
                            "--verbose", "--quiet"))  # fmt: skip
            twin.wait_for("page on", 90)
            commits = Commits(twin)
            stop = threading.Event()
            threading.Thread(target=commits.follow, args=(stop,), daemon=True).start()
            time.sleep(a.warmup)
            phases: dict = {}
            with busy(a.busy):
                t0 = time.time()
                time.sleep(a.seconds)
                phases["idle"] = commits.phase(t0, time.time())
                print(f"idle: {phases['idle']}", flush=True)
                t0 = time.time()
                answers = asyncio.run(_load(http, a.path, a.clients, a.seconds, a.rude))
                phases["clients"] = commits.phase(t0, time.time())
                print(f"{a.clients} clients: {phases['clients']}", flush=True)
                t0 = time.time()
                time.sleep(a.seconds)
                phases["after"] = commits.phase(t0, time.time())
                print(f"after: {phases['after']}", flush=True)
            stop.set()
            twin.stop(signal.SIGTERM)
        finally:
            for p in (twin, plant):
                if p is not None:
                    p.kill()
    codes = {str(k): len(v) for k, v in answers.items()}
    ok = np.array(answers.get(200, [np.nan])) * 1e3
    summary = {"clients": a.clients, "seconds": a.seconds, "path": a.path, "rude": a.rude,
               "load": f"busy {a.busy}" if a.busy else "idle", "answers": codes,
               "latency_200_ms": {"p50": float(np.nanpercentile(ok, 50)),
                                  "p99": float(np.nanpercentile(ok, 99))}, **phases}  # fmt: skip
    print(
        f"answers: {codes}; 200 latency p50 {summary['latency_200_ms']['p50']:.0f} ms, "
        f"p99 {summary['latency_200_ms']['p99']:.0f} ms"
    )
    for name in ("idle", "clients", "after"):
        ph = phases[name]
        age = ph["data_age_s"] or {}
        print(
            f"{name:8s} {ph['rows_per_s']:7.1f} rows/s, data age p50 {age.get('p50', float('nan')):.3f} s, "
            f"p99 {age.get('p99', float('nan')):.3f} s, max {age.get('max', float('nan')):.3f} s"
        )
    path = write_results("twin_viewers" + ("_rude" if a.rude else "") + ("_busy" if a.busy else ""),
                         [{"figure": "viewers", "unit": "rows/s, s, ms", **summary}])  # fmt: skip
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
