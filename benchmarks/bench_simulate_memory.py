"""Benchmark: peak memory of a long ``simulate`` and of refusing large junk data files.

Run: ``python benchmarks/bench_simulate_memory.py [--durations 60 600 3600] [--reduced]
[--junk-mb 200] [--src PATH]``. Each measurement is a fresh subprocess (``drafttwin simulate
--duration D --quiet --out tmp.parquet``; ``read_measurements`` of a junk CSV made in a
temporary folder and deleted afterwards); its peak resident set size is ``ru_maxrss`` from
``os.wait4``. ``--src`` runs another checkout's ``src`` (e.g. the code before a change) on the
same interpreter. Prints a table and writes ``benchmarks/results/simulate_memory.json``:
``{figure, value, unit}`` per measurement, with the machine and date.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, os.path.dirname(__file__))

from _machine import write_results  # noqa: E402

READ = (
    "import sys\nfrom drafttwin.data import read_measurements\nfrom drafttwin.errors import "
    "DataError\ntry:\n    read_measurements(sys.argv[1])\nexcept DataError as exc:\n"
    "    print(str(exc).splitlines()[0])\n"
)
CLI = "from drafttwin.cli import app\napp()\n"


def peak_rss_mb(argv: list[str], src: str | None, timeout_s: float) -> tuple[float, float, int]:
    """Peak RSS (MB) and wall time (s) of a child process, and its exit code (-9: killed
    after ``timeout_s``: a refusal that takes that long counts as a hang)."""
    env = dict(os.environ)
    if src:
        env["PYTHONPATH"] = src + os.pathsep + env.get("PYTHONPATH", "")
    start = time.perf_counter()
    child = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    timer = threading.Timer(timeout_s, child.kill)
    timer.start()
    try:
        _, status, usage = os.wait4(child.pid, 0)
    finally:
        timer.cancel()
    child.returncode = os.waitstatus_to_exitcode(status)
    return usage.ru_maxrss / 1024, time.perf_counter() - start, child.returncode


def write_junk(path: Path, size_mb: int, line_breaks: bool) -> None:
    """``size_mb`` MB of random bytes, or of one endless CSV line, written 1 MB at a time."""
    block = os.urandom(2**20) if line_breaks else b"1815," * (2**20 // 5)
    with open(path, "wb") as fh:
        for _ in range(size_mb):
            fh.write(block)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--durations", type=float, nargs="+", default=[60.0, 600.0, 3600.0])
    parser.add_argument("--reduced", action="store_true", help="simulate --reduced (faster)")
    parser.add_argument("--junk-mb", type=int, default=200)
    parser.add_argument("--src", help="PYTHONPATH of the drafttwin to measure (default: installed)")
    parser.add_argument("--label", default="", help="suffix of the figure names (e.g. before)")
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument("--timeout", type=float, default=1800.0, help="s per child (then killed)")
    args = parser.parse_args()
    figures = []
    tag = f" ({args.label})" if args.label else ""
    model = "reduced" if args.reduced else "full"
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "sim.parquet"
        for duration in args.durations:
            argv = [sys.executable, "-c", CLI, "simulate", "--duration", f"{duration:g}",
                    "--quiet", "--out", str(out), *(["--reduced"] if args.reduced else [])]  # fmt: skip
            mb, wall, rc = peak_rss_mb(argv, args.src, args.timeout)
            out.unlink(missing_ok=True)
            figures.append({"figure": f"simulate {duration:g} s ({model} model) to Parquet, peak "
                            f"RSS{tag}", "value": round(mb, 1), "unit": "MB",
                            "wall_s": round(wall, 1), "exit_code": rc})  # fmt: skip
            print(f"{figures[-1]['figure']}: {mb:.0f} MB ({wall:.0f} s, exit {rc})", flush=True)
        for kind, breaks in (("random binary", True), ("no line break", False)):
            junk = Path(tmp) / "junk.csv"
            write_junk(junk, args.junk_mb, breaks)
            mb, wall, rc = peak_rss_mb(
                [sys.executable, "-c", READ, str(junk)], args.src, min(args.timeout, 300.0)
            )
            junk.unlink()
            figures.append({"figure": f"refuse a {args.junk_mb} MB CSV ({kind}), peak RSS{tag}",
                            "value": round(mb, 1), "unit": "MB", "wall_s": round(wall, 2),
                            "exit_code": rc})  # fmt: skip
            print(f"{figures[-1]['figure']}: {mb:.0f} MB ({wall:.1f} s, exit {rc})", flush=True)
    if not args.no_write:
        name = "simulate_memory" + (f"_{args.label}" if args.label else "")
        print(f"wrote {write_results(name, figures)}")


if __name__ == "__main__":
    main()
