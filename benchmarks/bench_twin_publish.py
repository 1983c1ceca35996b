"""Does publishing slow the twin? Its p99 latency and rows with and without publishers.

    python benchmarks/bench_twin_publish.py [--model M.dtm] [--machines 8] [--seconds 20]
                                            [--hz 10,100] [--mqtt HOST:PORT]

A twin replays ``--machines`` copies of one plant record in real time (100 Hz each), once
without publishing and once per ``--hz`` with both publishers: its own OPC UA server and MQTT
(QoS 1) to Mosquitto (started on a free port when ``--mqtt`` is not given; Debian package
``mosquitto``). Per run: rows processed, the twin's latency (received -> stored and pushed)
p50/p99/max, and per publisher what was sent, dropped and failed. Without --model a parallel
hybrid is fitted on the record first (2 epochs, as in bench_twin.py). Prints a table and writes
benchmarks/results/twin_publish.json. Measure on an otherwise idle machine.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, os.path.dirname(__file__))

from _machine import write_results  # noqa: E402
from drafttwin.twin.build import build_service  # noqa: E402
from drafttwin.twin.publish import parse_publish, publishing  # noqa: E402


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _record(folder: Path, seconds: float) -> Path:
    from drafttwin.plant import Plant

    path = folder / "plant.parquet"
    Plant().run(seconds, 100.0, seed=1, scenario="speed-change").write(path)
    return path


def _model(path: str | None, record: Path, folder: Path) -> Path:
    if path is not None:
        return Path(path)
    from drafttwin.data.io import read_measurements
    from drafttwin.models import MechanisticModel, make_model

    model = make_model("parallel", "quick", epochs=2, quiet=True)
    model.fit(read_measurements(record), MechanisticModel.from_preset("fa320a"))
    out = folder / "parallel.dtm"
    model.save(out)
    return out


def _mosquitto(folder: Path) -> tuple[subprocess.Popen[bytes], int]:
    binary = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
    if not Path(binary).is_file():
        raise SystemExit("mosquitto is not installed: give --mqtt HOST:PORT of a broker")
    port = _port()
    conf = folder / "mosquitto.conf"
    conf.write_text(f"listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\n")
    proc = subprocess.Popen([binary, "-c", str(conf)], stderr=subprocess.DEVNULL)
    time.sleep(0.5)
    return proc, port


def _run(model: Path, record: Path, machines: int, targets: list[str]) -> dict[str, Any]:
    sources = [f"replay:{record}?speed=1&machine=m{k:02d}" for k in range(machines)]
    service = build_service(model, sources, detector="none")
    publishers = [parse_publish(t) for t in targets]

    async def go() -> None:
        async with publishing(service, publishers):
            await service.run()

    start = time.monotonic()
    asyncio.run(go())
    status = service.status()
    return {"rows": status["rows"], "wall_s": round(time.monotonic() - start, 2),
            "latency_ms": status["latency_ms"],
            "publishers": [p.summary() for p in publishers]}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model")
    ap.add_argument("--machines", type=int, default=8)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--hz", default="10,100")
    ap.add_argument("--mqtt")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        record = _record(folder, args.seconds)
        model = _model(args.model, record, folder)
        broker, mqtt = (None, args.mqtt) if args.mqtt else _mosquitto(folder)
        if broker is not None:
            mqtt = f"127.0.0.1:{mqtt}"
        try:
            figures = [{"hz": None, **_run(model, record, args.machines, [])}]
            for hz in (float(h) for h in args.hz.split(",")):
                targets = [f"opcua:opc.tcp://127.0.0.1:{_port()}?hz={hz:g}",
                           f"mqtt://{mqtt}?qos=1&hz={hz:g}"]  # fmt: skip
                figures.append({"hz": hz, **_run(model, record, args.machines, targets)})
        finally:
            if broker is not None:
                broker.terminate()
                broker.wait(timeout=10)
    print(f"{'publish hz':>10} {'rows':>7} {'p50 ms':>7} {'p99 ms':>7} {'max ms':>7}  publishers")
    for f in figures:
        lat = f["latency_ms"]
        pubs = "; ".join(f"{p['spec'].split(':')[0]} {p['sent']} sent {p['dropped']} dropped"
                         for p in f["publishers"])  # fmt: skip
        print(f"{'none' if f['hz'] is None else f['hz']:>10} {f['rows']:>7} {lat['p50']:7.2f} "
              f"{lat['p99']:7.2f} {lat['max']:7.2f}  {pubs}")  # fmt: skip
    for f in figures:
        f["machines"], f["seconds"] = args.machines, args.seconds
    print(write_results("twin_publish", figures))


if __name__ == "__main__":
    main()
