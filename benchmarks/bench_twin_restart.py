"""Kill -9 of a live twin and its restart, counted against the plant's own log.

    python benchmarks/bench_twin_restart.py [--model M.dtm] [--runs 3] [--history 0,60]

Per run: ``plant serve --opcua --log`` (with ``--history S`` when S > 0) and ``twin run
--commit-ms 100`` as subprocesses; the twin is killed with SIGKILL at a random point 0-100 ms
after its 8th acknowledged commit (seeded per run), started again on the same store, and both
are stopped with SIGTERM after 10 more commits. ``twin audit`` then counts the store against
the plant's log: samples lost by the kill (published before the SIGKILL, not stored), the
restart gap (published while no twin ran), samples recovered from the server's history,
stored twice, stored different. Without --model a parallel hybrid is fitted first (as in
bench_twin.py). Prints a table and writes benchmarks/results/twin_restart.json.
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, os.path.dirname(__file__))

from _machine import write_results  # noqa: E402
from drafttwin.twin.store.audit import audit  # noqa: E402
from drafttwin.twin.store.history import read_events  # noqa: E402
from drafttwin.wire.plantlog import read_plant_log  # noqa: E402

COMMIT_MS = 100


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-c", "from drafttwin.cli import main; main()", *args]


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _commits(proc: subprocess.Popen[str], n: int) -> list[dict[str, float]]:
    out: list[dict[str, float]] = []
    deadline = time.monotonic() + 120
    assert proc.stdout is not None
    while len(out) < n and time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        if line.startswith("commit "):
            out.append({k: float(v) for k, v in (f.split("=") for f in line.split()[1:])})
    if len(out) < n:
        raise RuntimeError(
            f"twin gave {len(out)} commits: {proc.stderr.read() if proc.stderr else ''}"
        )
    return out


def _stop(proc: subprocess.Popen[str], sig: int = signal.SIGTERM) -> None:
    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=30)


def one_run(model: Path, folder: Path, history_s: int, seed: int) -> dict[str, Any]:
    url = f"opc.tcp://127.0.0.1:{_port()}"
    log, store = folder / "plant.parquet", folder / "store"
    plant = subprocess.Popen(_cli("plant", "serve", "--opcua", url, "--physics", "reduced",
                                  "--log", str(log), "--history", str(history_s)),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    twin = ["twin", "run", "--model", str(model), "--source", f"opcua:{url}", "--store", str(store),
            "--commit-ms", str(COMMIT_MS), "--verbose", "--quiet"]  # fmt: skip
    procs = [plant]
    try:
        assert plant.stderr is not None and "serving" in plant.stderr.readline()
        first = subprocess.Popen(
            _cli(*twin), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        procs.append(first)
        acked = _commits(first, 8)
        time.sleep(random.Random(seed).uniform(0.0, 0.1))
        first.send_signal(signal.SIGKILL)
        killed_at = time.time()
        first.wait(timeout=30)
        second = subprocess.Popen(
            _cli(*twin), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        procs.append(second)
        resumed = _commits(second, 10)
        _stop(plant)
        time.sleep(1.0)
        _stop(second)
    finally:
        for p in procs:
            _stop(p, signal.SIGKILL)
    (m,) = audit(store, log)
    plant_log = read_plant_log(log)
    absent = plant_log[plant_log["seq"].isin([s for r in m.runs
                                              for s in range(r.first_seq, r.last_seq + 1)])]  # fmt: skip
    events = read_events(store)
    recovered = [int(d.split()[0]) for d in events.query("kind == 'history'")["detail"]
                 if d.split()[0].isdigit()]  # fmt: skip
    first_resumed = resumed[0]["at"]
    restart_published = plant_log[(plant_log["published"] > killed_at)
                                   & (plant_log["published"] < first_resumed)]  # fmt: skip
    return {
        "history_s": history_s,
        "lost_by_kill": int((absent["published"] <= killed_at).sum()),
        "bound_ms": COMMIT_MS + max(c["ms"] for c in acked) + 50,
        "restart_gap_absent": int((absent["published"] > killed_at).sum()),
        "published_while_down": len(restart_published),
        "restart_s": first_resumed - killed_at,
        "recovered_from_history": sum(recovered),
        "absent": m.missing_inside,
        "twice": m.duplicates,
        "differ": m.mismatched,
        "stored": m.stored,
        "published": m.published,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--model", default=None)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--history", default="0,60")
    args = parser.parse_args()
    histories = [int(x) for x in args.history.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        model = Path(args.model) if args.model else _fit(folder)
        rows = []
        print(f"{'history s':>9} {'lost by kill':>12} {'bound ms':>8} {'down s':>6} "
              f"{'sent while down':>15} {'recovered':>9} {'absent':>6} {'twice':>5} {'differ':>6}")  # fmt: skip
        for h in histories:
            for k in range(args.runs):
                run_dir = folder / f"h{h}-{k}"
                run_dir.mkdir()
                r = one_run(model, run_dir, h, seed=k)
                rows.append(r)
                print(f"{h:>9} {r['lost_by_kill']:>12} {r['bound_ms']:>8.0f} {r['restart_s']:>6.1f} "
                      f"{r['published_while_down']:>15} {r['recovered_from_history']:>9} "
                      f"{r['absent']:>6} {r['twice']:>5} {r['differ']:>6}", flush=True)  # fmt: skip
    figures = [{"figure": f"history {r['history_s']} s, run {i}: {k}", "value": r[k], "unit": u}
               for i, r in enumerate(rows)
               for k, u in (("lost_by_kill", "samples"), ("bound_ms", "ms"), ("restart_s", "s"),
                            ("published_while_down", "samples"), ("recovered_from_history", "samples"),
                            ("absent", "samples"), ("twice", "samples"), ("differ", "samples"))]  # fmt: skip
    print(f"wrote {write_results('twin_restart', figures)}")


def _fit(folder: Path) -> Path:
    from bench_twin import _model

    model, _ = _model(None, folder)
    path = folder / "parallel.dtm"
    model.save(path)
    return path


if __name__ == "__main__":
    main()
