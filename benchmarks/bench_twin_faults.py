"""Faults in the live twin: detection delay live vs offline on the same records, the probable
cause each names, and the CPU the detector adds per sample.

    python benchmarks/bench_twin_faults.py [--model M.dtm]

Records (the recorded plant, ``drafttwin generate``'s): two healthy ones of other machines set
the thresholds (``twin fit-detector``'s defaults: 1 false alarm per 24 h, 15 s baseline,
20 s post-alarm window, as offline); each faulted record is diagnosed offline (``Diagnoser.diagnose``,
what ``drafttwin diagnose`` runs) and replayed through the live path (``twin run
--source replay:FILE?speed=inf``: cleaning, reduced physics stepped per sample, the hybrid,
the live fault watch, the ranking in its worker process). Delay = alarm time minus the
fault's onset, in record time. CPU per sample: the live watch alone timed over the rows of
the replay (the twin's own rows, motor included), and a whole replay with and without it.
Without --model a parallel hybrid is fitted on a 20 s record first (quick profile, 2 epochs).
Prints a table and writes benchmarks/results/twin_faults.json.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))

from _machine import write_results  # noqa: E402
from drafttwin.diagnosis.detect import FaultDetector  # noqa: E402
from drafttwin.diagnosis.diagnose import Diagnoser  # noqa: E402
from drafttwin.diagnosis.residuals import record_features, roller_ratio  # noqa: E402
from drafttwin.plant import Machine, Plant  # noqa: E402
from drafttwin.plant.faults import FaultSpec  # noqa: E402
from drafttwin.twin.build import build_service, load_twin_model  # noqa: E402
from drafttwin.twin.faultwatch import LiveFaultWatch, detector_path, save_detector  # noqa: E402
from drafttwin.twin.live import physics_train  # noqa: E402
from drafttwin.twin.store.db import EventRow, SampleRow  # noqa: E402

CASES = (
    "main_belt:belt_wear:severity=0.5:onset=30",
    "front:load_loss:severity=0.3:onset=30:ramp=20",
    "main_shaft:bearing_friction:severity=5:onset=30",
    "third:gain:severity=0.003:onset=30:ramp=5",
    "motor:torque_loss:severity=0.15:onset=30",
)
DURATION_S = 75.0


def _record(plant: Plant, folder: Path, name: str, machine_seed: int, seed: int,
            duration: float, faults: tuple[str, ...] = ()) -> Path:  # fmt: skip
    m = Machine.draw(plant.train, plant.config, machine_seed)
    rec = plant.run(duration, 100.0, seed=seed, machine=m,
                    faults=[FaultSpec.parse(f) for f in faults])  # fmt: skip
    path = folder / f"{name}.parquet"
    rec.write(path)
    return path


def _model(path: str | None, folder: Path, plant: Plant) -> Path:
    if path is not None:
        return Path(path)
    from drafttwin.data.io import read_measurements
    from drafttwin.models import MechanisticModel, make_model

    record = folder / "train.parquet"
    plant.run(20.0, 100.0, seed=5, scenario="speed-change").write(record)
    model = make_model("parallel", "quick", epochs=2, quiet=True)
    model.fit(read_measurements(record), MechanisticModel.from_preset("fa320a"))
    out = folder / "bench.dtm"
    model.save(out)
    return out


def _live(model: Path, record: Path, detector: str) -> dict[str, Any]:
    """One replay at full speed: its fault events (with wall times), rows and CPU."""
    # learn_s 0: the detector file judges the machine as it is (offline's thresholds)
    service = build_service(model, [f"replay:{record}?speed=inf"], detector=detector,
                            learn_s=0.0)  # fmt: skip
    events: list[tuple[EventRow, float]] = []
    rows: list[SampleRow] = []
    service.event_hooks.append(lambda ev: events.append((ev, time.monotonic())))
    service.subscribers.append(lambda _m, r, _e: rows.extend(r))
    cpu0 = time.process_time()
    asyncio.run(service.run())
    cpu = time.process_time() - cpu0
    return {"events": events, "rows": rows, "cpu_s": cpu, "n": service.rows}


def _watch_cost(detector: FaultDetector, rows: list[SampleRow], ratio: np.ndarray,
                repeats: int = 3) -> float:  # fmt: skip
    """Microseconds per row of the live watch alone (the best of ``repeats``)."""
    best = np.inf
    for _ in range(repeats):
        watch = LiveFaultWatch("m", ("front", "second", "third", "back"), 100.0, ratio,
                               baseline=detector)  # fmt: skip
        t0 = time.perf_counter()
        for r in rows:
            watch.add(r)
        best = min(best, (time.perf_counter() - t0) / len(rows) * 1e6)
    return float(best)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--model", default=None)
    args = parser.parse_args()
    import json

    import torch

    torch.set_num_threads(1)
    plant = Plant()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        model = _model(args.model, folder, plant)
        healthy = [_record(plant, folder, f"healthy{i}", 50 + i, 60 + i, 40.0) for i in range(2)]
        train = physics_train(load_twin_model(model), "reduced")
        det = FaultDetector().fit([record_features(train, _series(p)) for p in healthy])
        save_detector(detector_path(model), det, model, [str(p) for p in healthy])
        offline = Diagnoser(physics_train(load_twin_model(model), "full"), det)
        print(f"{'fault':<52} {'offline s':>9} {'live s':>7} {'cause wait s':>12}  "
              "offline cause / live cause")  # fmt: skip
        results, figures = [], []
        for k, case in enumerate(CASES):
            spec = FaultSpec.parse(case)
            rec = _record(plant, folder, f"case{k}", 70 + k, 80 + k, DURATION_S, (case,))
            dx = offline.diagnose(_series(rec))
            live = _live(model, rec, str(detector_path(model)))
            r = _case(case, spec.onset_s, dx, live["events"])
            results.append(r)
            print(f"{case:<52} {_f(r['offline_delay_s']):>9} {_f(r['live_delay_s']):>7} "
                  f"{_f(r['cause_wait_wall_s']):>12}  {r['offline_cause']} / {r['live_cause']}")  # fmt: skip
        base = _live(model, healthy[0], "none")
        watched = _live(model, healthy[0], str(detector_path(model)))
        per_row_us = _watch_cost(det, watched["rows"], roller_ratio(train))
        added = (watched["cpu_s"] - base["cpu_s"]) / max(1, watched["n"]) * 1e6
        print(f"live watch alone: {per_row_us:.1f} us per sample; whole replay with vs without "
              f"the detector: {base['cpu_s'] / base['n'] * 1e6:.0f} -> "
              f"{watched['cpu_s'] / watched['n'] * 1e6:.0f} us per sample ({added:+.1f}); "
              f"healthy replay alarms: {_count(watched['events'])}")  # fmt: skip
    for r in results:
        for key, unit in (("offline_delay_s", "s"), ("live_delay_s", "s"),
                          ("cause_wait_wall_s", "s (wall, replay at full speed)")):  # fmt: skip
            figures.append({"figure": f"{r['case']}: {key}", "value": r[key], "unit": unit})
        figures.append({"figure": f"{r['case']}: causes", "value": json.dumps(
            {"offline": r["offline_cause"], "live": r["live_cause"]}), "unit": "element:kind"})  # fmt: skip
    figures += [
        {"figure": "live fault watch CPU per sample", "value": per_row_us, "unit": "us"},
        {"figure": "replay CPU per sample without detector", "value": base["cpu_s"] / base["n"] * 1e6,
         "unit": "us"},
        {"figure": "replay CPU per sample with detector", "value": watched["cpu_s"] / watched["n"] * 1e6,
         "unit": "us"},
        {"figure": "healthy replay fault alarms", "value": _count(watched["events"]), "unit": "alarms"},
    ]  # fmt: skip
    print(f"wrote {write_results('twin_faults', figures)}")


def _series(path: Path) -> Any:
    from drafttwin.data.io import read_measurements

    return read_measurements(path)


def _count(events: list[tuple[EventRow, float]]) -> int:
    return sum(1 for ev, _ in events if ev.kind in ("fault", "sensor-fault"))


def _case(case: str, onset: float, dx: Any, events: list[tuple[EventRow, float]]) -> dict[str, Any]:
    import json

    alarm = next(((ev, w) for ev, w in events if ev.kind in ("fault", "sensor-fault")), None)
    cause = next(((ev, w) for ev, w in events if ev.kind == "fault-cause"), None)
    live_alarm = None if alarm is None else json.loads(alarm[0].detail)
    source = cause if cause is not None else alarm
    causes = [] if source is None else json.loads(source[0].detail).get("causes", [])
    return {
        "case": case,
        "offline_delay_s": None if dx.alarm is None else dx.alarm.time_s - onset,
        "live_delay_s": None if live_alarm is None else live_alarm["alarm_s"] - onset,
        "cause_wait_wall_s": None if cause is None or alarm is None else cause[1] - alarm[1],
        "offline_cause": dx.causes[0].name if dx.causes else None,
        "live_cause": f"{causes[0]['element']}:{causes[0]['kind']}" if causes else None,
    }


def _f(x: float | None) -> str:
    return "-" if x is None else f"{x:.1f}"


if __name__ == "__main__":
    main()
