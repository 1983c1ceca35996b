"""How fast every long-running command stops on SIGTERM (or SIGINT), idle or beside busy
processes: the time from the signal to the process's exit, its exit code, and whether its
stderr holds a traceback or a warning flood.

    python benchmarks/bench_stop.py [--tries 10] [--busy 2] [--signal TERM]
                                    [--cases twin-opcua-page,twin-opcua-alarm,...]

Cases (each started afresh per try; the twin's plant is started once per case):

* ``plant-opcua``, ``plant-mqtt``: ``plant serve`` with full physics (MQTT on Mosquitto when
  installed, else the embedded broker), stopped 2 s after it said it serves;
* ``twin-opcua-page``, ``twin-mqtt-page``: ``twin run`` on a served plant with the page on, a
  browser's and a scraper's requests made, stopped 2 s later;
* ``twin-opcua-alarm``: ``twin run`` without the page on a plant with a belt fault at 35 s
  (past the detector's 15-s reference from the twin's start), stopped
  1 s after its alarm (its probable cause still being ranked);
* ``twin-replay-page``: ``twin run`` replaying a record with the page on;
* ``hall``: ``twin hall`` with 2 shards (private Ray), stopped 2 s after both shards said
  they run; ``hall-starting``: stopped 15 s after its start, whatever its shards are doing (on
  a busy box they are still starting: its summary then names them as ended).

``--busy N`` runs N processes spinning a core beside each try (the issue's "two busy
neighbours"). Prints a table and writes benchmarks/results/stop.json (or ``stop_busy.json``).
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, os.path.dirname(__file__))

from _machine import busy, write_results  # noqa: E402

LIMIT_S = 5.0
"""What docs/twin.md promises."""
SRC = str(Path(__file__).resolve().parents[1] / "src")


def cli(*args: str) -> list[str]:
    return [sys.executable, "-c", "from drafttwin.cli import main; main()", *args]


def env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": SRC, "OMP_NUM_THREADS": "1"}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Proc:
    """A command whose stderr is read by a thread (lines kept, waited on by text)."""

    def __init__(self, args: list[str]) -> None:
        self.p = subprocess.Popen(args, env=env(), stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True)  # fmt: skip
        self.lines: list[str] = []
        self.out: list[str] = []
        self._t = threading.Thread(target=self._read, daemon=True)
        self._t.start()
        self._o = threading.Thread(target=lambda: self.out.extend(self.p.stdout or []), daemon=True)
        self._o.start()

    def _read(self) -> None:
        assert self.p.stderr is not None
        for line in self.p.stderr:
            self.lines.append(line)

    def wait_for(self, text: str, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if any(text in line for line in self.lines):
                return
            if self.p.poll() is not None:
                break
            time.sleep(0.05)
        raise RuntimeError(f"no {text!r} within {timeout:g} s from {self.p.args[3:6]}: "
                           + "".join(self.lines[-20:]))  # fmt: skip

    def stop(self, sig: int, wait_s: float = 60.0) -> dict:
        """Signal; seconds to exit, exit code, what stderr said."""
        n = len(self.lines)
        t0 = time.monotonic()
        self.p.send_signal(sig)
        try:
            self.p.wait(wait_s)
        except subprocess.TimeoutExpired:
            self.p.kill()
            self.p.wait(30)
        took = time.monotonic() - t0
        self._t.join(5)
        self._o.join(5)
        after = "".join(self.lines[n:])
        said = after + "".join(self.out)
        return {"stop_s": took, "rc": self.p.returncode,
                "summary": any(w in said for w in ("published", "committed", "latency", "ended)")),
                "traceback": "Traceback" in after, "warnings": after.count("Warning") +
                after.count("WARNING"), "tail": after[-400:]}  # fmt: skip

    def kill(self) -> None:
        if self.p.poll() is None:
            self.p.kill()
            self.p.wait(30)


@dataclass
class Setup:
    folder: Path
    model: Path = field(init=False)
    record: Path = field(init=False)
    mosquitto: str | None = field(default_factory=lambda: shutil.which("mosquitto") or (
        "/usr/sbin/mosquitto" if Path("/usr/sbin/mosquitto").is_file() else None))  # fmt: skip

    def make(self) -> None:
        """A healthy record of machine 7, a tiny hybrid on it and its detector."""
        self.record = self.folder / "healthy.parquet"
        self.model = self.folder / "tiny.dtm"
        for args in (["generate", "--duration", "120", "--machine-seed", "7", "--seed", "1",
                      "--out", str(self.record)],
                     ["fit", "--model", "parallel", "--data", str(self.record), "--out",
                      str(self.model), "--epochs", "2", "--set", "window=8,hidden=8,layers=1",
                      "--quiet"],
                     ["twin", "fit-detector", "--model", str(self.model), "--healthy",
                      str(self.record)]):  # fmt: skip
            subprocess.run(cli(*args), env=env(), check=True, capture_output=True)


@contextmanager
def broker(setup: Setup) -> Iterator[str]:
    """A Mosquitto broker on a free port (or none: the plant starts its embedded one)."""
    port = free_port()
    if setup.mosquitto is None:
        yield f"127.0.0.1:{port}"
        return
    conf = setup.folder / f"mosquitto-{port}.conf"
    conf.write_text(f"listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\n",
                    encoding="utf-8")  # fmt: skip
    proc = subprocess.Popen([setup.mosquitto, "-c", str(conf)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)  # fmt: skip
    time.sleep(0.5)
    try:
        yield f"127.0.0.1:{port}"
    finally:
        proc.kill()
        proc.wait()


@contextmanager
def plant(kind: str, address: str, *extra: str) -> Iterator[Proc]:
    p = Proc(cli("plant", "serve", f"--{kind}", address, *extra))
    try:
        p.wait_for("serving", 90)
        yield p
    finally:
        p.kill()


def visit(port: int) -> None:
    for path in ("/", "/api/status", "/metrics", "/api/history/fa320a?seconds=10"):
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=10) as r:
                r.read()
        except OSError:
            pass


def twin_tries(setup: Setup, source: str, tries: int, sig: int, page: bool, store: bool,
               trigger: Callable[[Proc], None], *extra: str, first: int = 1) -> list[dict]:  # fmt: skip
    """``tries`` runs of ``twin run`` on ``source``, each stopped by ``sig`` after ``trigger``;
    printed as tries ``first``, ``first + 1``, ..."""
    out = []
    for k in range(tries):
        args = ["twin", "run", "--model", str(setup.model), "--source", source, *extra]
        http = free_port()
        if page:
            args += ["--http", f"127.0.0.1:{http}"]
        if store:
            args += ["--store", str(setup.folder / f"store-{time.monotonic_ns()}")]
        twin = Proc(cli(*args))
        try:
            twin.wait_for("page on" if page else "identity", 90)
            if page:
                visit(http)
            trigger(twin)
            out.append(twin.stop(sig))
        finally:
            twin.kill()
        print(f"  try {first + k}: {out[-1]['stop_s']:.2f} s, rc {out[-1]['rc']}", flush=True)
    return out


def case(name: str, setup: Setup, tries: int, sig: int) -> list[dict]:
    wait2: Callable[[Proc], None] = lambda _p: time.sleep(2.0)  # noqa: E731
    if name.startswith("plant-"):
        kind = name.split("-")[1]
        out = []
        for _ in range(tries):
            addr = f"opc.tcp://127.0.0.1:{free_port()}" if kind == "opcua" else None
            with broker(setup) if kind == "mqtt" else _nothing() as b:
                p = Proc(cli("plant", "serve", f"--{kind}", addr or b))
                try:
                    p.wait_for("serving", 90)
                    time.sleep(2.0)
                    out.append(p.stop(sig))
                finally:
                    p.kill()
            print(f"  try {len(out)}: {out[-1]['stop_s']:.2f} s, rc {out[-1]['rc']}", flush=True)
        return out
    if name == "twin-opcua-page":
        url = f"opc.tcp://127.0.0.1:{free_port()}"
        with plant("opcua", url, "--physics", "reduced"):
            return twin_tries(setup, f"opcua:{url}", tries, sig, True, True, wait2)
    if name == "twin-mqtt-page":
        with broker(setup) as b, plant("mqtt", b, "--physics", "reduced"):
            return twin_tries(setup, f"mqtt://{b}", tries, sig, True, True, wait2)
    if name == "twin-opcua-alarm":
        out = []
        for _ in range(tries):  # a fresh plant each try: the fault's onset is from its start
            url = f"opc.tcp://127.0.0.1:{free_port()}"
            with plant("opcua", url, "--seed", "7", "--fault",
                       "main_belt:belt_wear:severity=0.8:onset=35"):  # fmt: skip
                out += twin_tries(setup, f"opcua:{url}", 1, sig, False, True,
                                  lambda t: (t.wait_for("ALARM", 120), time.sleep(1.0)),
                                  "--learn", "0", first=len(out) + 1)  # fmt: skip
        return out
    if name == "twin-replay-page":
        return twin_tries(setup, f"replay:{setup.record}?speed=1", tries, sig, True, False, wait2)
    if name in ("hall", "hall-starting"):
        mapping = setup.folder / "hall.toml"
        mapping.write_text("".join(f'[[machine]]\nname = "fa320a-{k}"\n\n' for k in (1, 2, 3)),
                           encoding="utf-8")  # fmt: skip
        url = f"opc.tcp://127.0.0.1:{free_port()}"
        out = []
        with plant("opcua", url, "--machines", "3", "--physics", "reduced"):
            for _ in range(tries):
                h = Proc(cli("twin", "hall", "--model", str(setup.model), "--source",
                             f"opcua:{url}", "--mapping", str(mapping), "--store",
                             str(setup.folder / f"hall-{time.monotonic_ns()}"), "--shards", "2"))  # fmt: skip
                try:
                    if name == "hall":  # both shards running (their status line), then 2 s
                        h.wait_for("shard 0: running", 180)
                        h.wait_for("shard 1: running", 60)
                        time.sleep(2.0)
                    else:  # stopped 15 s after its start, whatever its shards are doing
                        time.sleep(15.0)
                    out.append(h.stop(sig))
                finally:
                    h.kill()
                print(
                    f"  try {len(out)}: {out[-1]['stop_s']:.2f} s, rc {out[-1]['rc']}", flush=True
                )
        return out
    raise SystemExit(f"unknown case {name!r}")


@contextmanager
def _nothing() -> Iterator[None]:
    yield None


CASES = ("plant-opcua", "plant-mqtt", "twin-opcua-page", "twin-mqtt-page", "twin-opcua-alarm",
         "twin-replay-page", "hall", "hall-starting")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tries", type=int, default=10)
    ap.add_argument("--busy", type=int, default=0, help="processes spinning a core beside")
    ap.add_argument("--signal", default="TERM", choices=["TERM", "INT"])
    ap.add_argument("--cases", default=",".join(CASES))
    a = ap.parse_args()
    sig = signal.SIGTERM if a.signal == "TERM" else signal.SIGINT
    figures = []
    with tempfile.TemporaryDirectory(prefix="bench-stop-") as tmp:
        setup = Setup(Path(tmp))
        print("making a record, a tiny model and its detector ...", flush=True)
        setup.make()
        with busy(a.busy):
            for name in a.cases.split(","):
                print(f"{name}: {a.tries} tries, SIG{a.signal}, {a.busy} busy", flush=True)
                res = case(name, setup, a.tries, sig)
                times = [r["stop_s"] for r in res]
                bad = [r for r in res if r["rc"] != 0 or r["traceback"] or r["warnings"] > 2
                       or not r["summary"]]  # fmt: skip
                fig = {"case": name, "figure": "stop", "unit": "s", "tries": len(res),
                       "median": statistics.median(times), "max": max(times),
                       "over_limit": sum(t >= LIMIT_S for t in times), "failed": len(bad),
                       "load": f"busy {a.busy}" if a.busy else "idle",
                       "signal": f"SIG{a.signal}", "times": [round(t, 2) for t in times],
                       "failures": [b["tail"] for b in bad][:3]}  # fmt: skip
                figures.append(fig)
                print(
                    f"{name}: median {fig['median']:.2f} s, max {fig['max']:.2f} s, "
                    f"{fig['over_limit']} over {LIMIT_S:g} s, {fig['failed']} failed",
                    flush=True,
                )
    path = write_results("stop_busy" if a.busy else "stop", figures)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
