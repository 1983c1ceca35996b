"""Live twin load: machines at 100 Hz in one process, ramped until it saturates.

    python benchmarks/bench_twin.py [--model M.dtm] [--seconds 5] [--machines 1,2,5,10,20,50]
                                    [--detector] [--busy 2] [--processes K]

An in-process feed ticks at 100 Hz and hands every machine one sample per tick (rows of a
plant record, the set-point included), as a source would; each machine runs the whole live
hybrid (causal cleaning, reduced physics stepped to the set-point, the model through its
incremental predictor), every row goes to the DuckDB writer (commit every 200 ms) and to the
page's WebSocket hub, and the Prometheus metrics count it. Latency: sample handed over ->
row queued for the store and pushed to the hub (the commit adds at most one commit interval
plus the commit's own time, reported apart). Saturation: fewer than 95 % of the offered
samples processed, or p99 above 100 ms. Without --model a parallel hybrid is fitted on a
20 s plant record first (quick profile, 2 epochs). With --detector every machine also runs
the live fault watch (a detector fitted on the record itself, 5 s baseline; the feed carries
the motor speed) and the results go to twin_detector.json. With --busy N, N processes spin a
core each beside it (the busy neighbours of a shared box; results in ..._busy.json). Prints a
table (CPU per machine in ms of core time per second) and writes benchmarks/results/twin.json.
With --processes K, K such twin processes run at once as Ray tasks of one CPU each (a hall as
``twin hall`` shards it, each process with its own feed), per count of --machines: each
process's row and the hall's worst p99 (results in twin_hall.json).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))

from _machine import busy, write_results  # noqa: E402
from drafttwin.data.io import read_measurements  # noqa: E402
from drafttwin.diagnosis.detect import FaultDetector  # noqa: E402
from drafttwin.diagnosis.residuals import roller_ratio  # noqa: E402
from drafttwin.models.estimators.base import BaseModel  # noqa: E402
from drafttwin.twin.faultwatch import LiveFaultWatch, block_phase  # noqa: E402
from drafttwin.twin.live import MachineTwin, physics_train  # noqa: E402
from drafttwin.twin.service import MachineState, TwinService  # noqa: E402
from drafttwin.twin.sources.base import Emit, Report, Sample, Source  # noqa: E402
from drafttwin.twin.sources.mapping import MachineMap  # noqa: E402
from drafttwin.twin.store.db import StoreWriter, TwinStore  # noqa: E402
from drafttwin.twin.web.app import create_app  # noqa: E402

RATE = 100.0


class Feed(Source):
    """All machines' samples at 100 Hz from one ticker (rows of a record, cycled)."""

    def __init__(self, names: list[str], record: Path) -> None:
        self.machines = tuple(MachineMap(n, ("front", "second", "third", "back")) for n in names)
        self.spec = "in-process feed"
        s = read_measurements(record)
        self.values, self.setpoint = s.values, s.inputs["supply_hz"]
        self.motor = s.motor_rpm if s.motor_rpm is not None else np.full(len(s.values), np.nan)

    async def run(self, emit: Emit, report: Report) -> None:
        self._set("live", report)
        start, k = time.monotonic(), 0
        t0 = int(time.time() * 1e6)
        n = len(self.values)
        while True:
            k += 1
            delay = start + k / RATE - time.monotonic()
            # always yield: a loop behind schedule must still let the others run
            await asyncio.sleep(max(delay, 0.0))
            i = k % n
            ts = t0 + k * 10_000
            for m in self.machines:
                emit(Sample(m.name, ts, k, self.values[i], float(self.setpoint[i]),
                            float(self.motor[i])))  # fmt: skip


async def _step(model: BaseModel, record: Path, n: int, seconds: float, folder: Path,
                detector: FaultDetector | None = None) -> dict:  # fmt: skip
    names = [f"m{j:03d}" for j in range(n)]
    feed = Feed(names, record)
    states = {}
    train = physics_train(model, "reduced")
    for m in feed.machines:
        twin = MachineTwin(m.name, model, RATE, train=train)
        twin.warm_up()
        states[m.name] = MachineState(twin, m, feed.spec, model_key="bench")
        if detector is not None:
            phase = block_phase(m.name, RATE, detector.block_s_)  # as twin run does
            states[m.name].watch = LiveFaultWatch(m.name, m.channels, RATE, roller_ratio(train),
                                                  baseline=detector, phase=phase)  # fmt: skip
    store = TwinStore(folder / f"store{n}")
    writer = StoreWriter(store, 200.0)
    service = TwinService(states, [feed], writer)
    if detector is not None:  # the ranking's worker is started before the clock runs
        service.locator.register("bench", physics_train(model, "full"))
        for ready in service.locator.warm():
            ready.result()
    app = create_app(service)
    client: asyncio.Queue[str] = asyncio.Queue()
    app.state.hub.clients.add(client)

    async def pump() -> None:
        while True:
            await asyncio.sleep(0.05)
            app.state.hub.flush()
            while not client.empty():
                client.get_nowait()

    pusher = asyncio.create_task(pump())
    warm = 1.0
    run = asyncio.create_task(service.run(duration_s=warm + seconds))
    await asyncio.sleep(warm)
    service.latency_s.clear()
    rows0, cpu0, wall0 = service.rows, time.process_time(), time.monotonic()
    await run
    wall = time.monotonic() - wall0
    cpu = time.process_time() - cpu0
    pusher.cancel()
    writer.close()
    store.close()
    lat = np.asarray(service.latency_s) * 1e3
    commits = np.asarray(writer.commit_seconds) * 1e3
    processed = (service.rows - rows0) / wall
    return {
        "machines": n,
        "offered_samples_per_s": n * RATE,
        "processed_samples_per_s": processed,
        "latency_p50_ms": float(np.percentile(lat, 50)) if lat.size else None,
        "latency_p99_ms": float(np.percentile(lat, 99)) if lat.size else None,
        "latency_max_ms": float(lat.max()) if lat.size else None,
        "cpu_s_per_s": cpu / wall,
        "commit_p99_ms": float(np.percentile(commits, 99)) if commits.size else None,
        "committed_rows": writer.committed,
        "fault_alarms": sum(st.faults for st in states.values()),
    }


def _one_process(model_file: Path, record: Path, n: int, seconds: float, detector: bool,
                 folder: Path) -> dict:  # fmt: skip
    """One twin process of a hall: ``n`` machines from its own feed, as :func:`_step`."""
    import torch

    from drafttwin.models.registry import load_model

    torch.set_num_threads(1)
    model = load_model(model_file)
    folder.mkdir(parents=True, exist_ok=True)
    return asyncio.run(_step(model, record, n, seconds, folder, _detector(model, record)
                             if detector else None))  # fmt: skip


def _hall(model: BaseModel, record: Path, n: int, processes: int, seconds: float,
          detector: bool, folder: Path) -> list[dict]:  # fmt: skip
    """``processes`` twin processes of ``n`` machines each, one Ray task (1 CPU) each, run at
    once on a private Ray instance (as ``twin hall`` starts its shards)."""
    from drafttwin.execution.executor import ray_session

    model_file = model.save(folder / "model.dtm")
    with ray_session(processes, None) as ray:
        task = ray.remote(num_cpus=1)(_one_process)
        refs = [task.remote(model_file, record, n, seconds, detector, folder / f"p{k}")
                for k in range(processes)]  # fmt: skip
        return list(ray.get(refs))


def _detector(model: BaseModel, record: Path) -> FaultDetector:
    """A detector fitted on the record itself (5 s baseline)."""
    from drafttwin.diagnosis.residuals import record_features

    feats = record_features(physics_train(model, "reduced"), read_measurements(record))
    return FaultDetector(reference_s=5.0).fit([feats])


def _model(path: str | None, folder: Path) -> tuple[BaseModel, Path]:
    from drafttwin.models import MechanisticModel, make_model
    from drafttwin.models.registry import load_model
    from drafttwin.plant import Plant

    record = folder / "plant.parquet"
    Plant().run(20.0, RATE, seed=5, scenario="speed-change").write(record)
    if path is not None:
        return load_model(path), record
    series = read_measurements(record)
    model = make_model("parallel", "quick", epochs=2, quiet=True)
    model.fit(series, MechanisticModel.from_preset("fa320a"))
    return model, record


def _load(args: argparse.Namespace) -> str:
    """The load the figures were taken under, as the results name it."""
    return f"busy {args.busy}" if args.busy else "idle"


def _result_name(stem: str, args: argparse.Namespace) -> str:
    """``STEM[_detector][_busy]``: one results file per variant."""
    return stem + ("_detector" if args.detector else "") + ("_busy" if args.busy else "")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--model", default=None)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--machines", default="1,2,5,10,20,35,50")
    parser.add_argument("--detector", action="store_true", help="run the live fault watch too")
    parser.add_argument("--busy", type=int, default=0, help="processes spinning beside it")
    parser.add_argument("--processes", type=int, default=1,
                        help="twin processes (Ray tasks of 1 CPU), each with --machines")  # fmt: skip
    args = parser.parse_args()
    if args.processes > 1:
        hall_main(args)
        return
    import torch

    torch.set_num_threads(1)
    counts = [int(x) for x in args.machines.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        model, record = _model(args.model, folder)
        detector = _detector(model, record) if args.detector else None
        rows = []
        load = _load(args)
        print(f"{load}; {'machines':>8} {'offered/s':>10} {'done/s':>8} {'p50 ms':>7} {'p99 ms':>7} "
              f"{'max ms':>7} {'cpu s/s':>7} {'cpu ms/s/machine':>16} {'commit p99 ms':>13}")  # fmt: skip
        for n in counts:
            with busy(args.busy):
                r = asyncio.run(_step(model, record, n, args.seconds, folder, detector))
            r["load"] = load
            r["cpu_ms_per_s_per_machine"] = r["cpu_s_per_s"] / n * 1e3
            rows.append(r)
            print(f"{n:>8} {r['offered_samples_per_s']:>10.0f} {r['processed_samples_per_s']:>8.0f} "
                  f"{r['latency_p50_ms']:>7.2f} {r['latency_p99_ms']:>7.2f} {r['latency_max_ms']:>7.1f} "
                  f"{r['cpu_s_per_s']:>7.2f} {r['cpu_ms_per_s_per_machine']:>16.2f} "
                  f"{r['commit_p99_ms'] or 0:>13.1f}", flush=True)  # fmt: skip
            saturated = (r["processed_samples_per_s"] < 0.95 * r["offered_samples_per_s"]
                         or (r["latency_p99_ms"] or 0) > 100)  # fmt: skip
            if saturated:
                print(f"saturated at {n} machines")
                break
    ok = [r for r in rows if r["processed_samples_per_s"] >= 0.95 * r["offered_samples_per_s"]
          and (r["latency_p99_ms"] or 0) <= 20]  # fmt: skip
    figures = [
        {"figure": "machines kept at 100 Hz with p99 <= 20 ms", "value": max((r["machines"] for r in ok), default=0),
         "unit": "machines", "load": load},
        *({"figure": f"{r['machines']} machines: {k}", "value": v, "unit": u, "load": load}
          for r in rows for k, u in (("processed_samples_per_s", "samples/s"),
                                     ("latency_p99_ms", "ms"), ("cpu_s_per_s", "core s/s"),
                                     ("cpu_ms_per_s_per_machine", "core ms/s per machine"))
          for v in [r[k]]),
    ]  # fmt: skip
    if args.detector:
        figures += [{"figure": f"{r['machines']} machines: fault alarms", "value": r["fault_alarms"],
                     "unit": "alarms", "load": load} for r in rows]  # fmt: skip
    print(f"wrote {write_results(_result_name('twin', args), figures)}")


def hall_main(args: argparse.Namespace) -> None:
    """--processes K: K twin processes at once, each with every count of --machines."""
    load = _load(args)
    figures = []
    print(f"{load}; {args.processes} processes on Ray; per process: {'machines':>8} "
          f"{'done/s':>8} {'p50 ms':>7} {'p99 ms':>7} {'max ms':>7} {'cpu s/s':>7}")  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        model, record = _model(args.model, folder)
        for n in (int(x) for x in args.machines.split(",")):
            with busy(args.busy):
                rows = _hall(model, record, n, args.processes, args.seconds, args.detector,
                             folder / f"n{n}")  # fmt: skip
            for k, r in enumerate(rows):
                print(f"process {k}: {n:>8} {r['processed_samples_per_s']:>8.0f} "
                      f"{r['latency_p50_ms']:>7.2f} {r['latency_p99_ms']:>7.2f} "
                      f"{r['latency_max_ms']:>7.1f} {r['cpu_s_per_s']:>7.2f}", flush=True)  # fmt: skip
            worst = max(r["latency_p99_ms"] or 0.0 for r in rows)
            done = sum(r["processed_samples_per_s"] for r in rows)
            print(f"hall of {args.processes} x {n}: {done:.0f} of {args.processes * n * RATE:.0f} "
                  f"samples/s, worst p99 {worst:.2f} ms")  # fmt: skip
            figures += [
                {"figure": f"{args.processes} x {n} machines: worst process p99", "value": worst,
                 "unit": "ms", "load": load},
                {"figure": f"{args.processes} x {n} machines: processed", "value": done,
                 "unit": "samples/s", "load": load},
                {"figure": f"{args.processes} x {n} machines: cpu per machine",
                 "value": sum(r["cpu_s_per_s"] for r in rows) / (args.processes * n) * 1e3,
                 "unit": "core ms/s per machine", "load": load},
            ]  # fmt: skip
    print(f"wrote {write_results(_result_name('twin_hall', args), figures)}")


if __name__ == "__main__":
    main()
