"""The live benchmark: the fault benchmark's own records served over the wire, the twin
watching each machine as it would a live one, scored as the offline benchmark is.

What runs (``drafttwin benchmark faults --live``), each piece the shipped one in a process of
its own, talking MQTT on 127.0.0.1:

* the records: the offline benchmark's (:mod:`.records`, made once and kept), and before each
  test record a *prelude* of the same machine (its own recording seed, :data:`PRELUDE_S`):
  the healthy running it learns on, as a machine new to the twin does;
* a broker: Mosquitto when installed, else the embedded one (in this process);
* ``drafttwin plant replay``: ``machines`` slots, each playing prelude, record, prelude,
  record... of its share (a gap between files is a stop; each machine's identity retained
  before its files), at ``speed`` times real time;
* ``drafttwin twin run``: the physics model of the benchmark (the fa320a preset, reduced) with
  its detector file fitted on the benchmark's tuning records as the prior: each machine
  learns its own healthy state (2 min), then watches; every alarm and its cause go to its
  store;
* this process: the twin's events, read back with ``twin query``, each alarm placed in its
  record by the replay's manifest (source times), scored as :mod:`.score` scores the offline
  run, beside the offline physics diagnosis of the same records.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import shutil
import signal
import subprocess
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drafttwin.errors import RunError
from drafttwin.execution.executor import run_tasks
from drafttwin.studies.faults.harness import (
    LEARN_MARGIN_S,
    broker,
    child_process,
    cli_command,
    free_port,
    run_command,
    twin_events,
    twin_status,
    wait_live,
)
from drafttwin.studies.faults.plan import BenchmarkPlan, plant_record, run_record, task_configs
from drafttwin.studies.faults.records import record_path
from drafttwin.studies.faults.score import onset_of, outcome, physics_rows, score

PRELUDE_S = 130.0
"""Healthy running before each test record, s: the machine learns :data:`LEARN_MARGIN_S`
less (120 s, what it needs on top of a prior that watches the lags), its blocks being final a
block late."""
GAP_S = 10.0
"""Silence between two files of a slot, s of source time (the twin's physics restarts)."""
MACHINES = 10
SPEED = 4.0
"""Times real time per machine: 10 machines x 4 x 100 Hz = 4000 samples/s, what one twin
process keeps up with on 2 cores beside the replay and the broker (at 8x it fell behind:
about 4600 samples/s was its most there; docs/faults.md, "Live: the benchmark's records
served to the twin")."""
STALL_S = 60.0
"""Wall time without a received sample, after the replay is out, before the twin is stopped."""


@dataclass(frozen=True)
class LivePlan:
    """How the records are served: machines at once, speed, samples per message."""

    machines: int = MACHINES
    speed: float = SPEED
    batch: int = 20
    prelude_s: float = PRELUDE_S
    plant_machines: int = 4  # the shorter run against 'plant serve' (0: none)
    plant_s: float = 600.0


def prelude_config(task: dict[str, Any]) -> dict[str, Any]:
    """The healthy running a test record's machine learns on: the same machine, its own
    recording seed (drawn from the record's), no fault."""
    digest = hashlib.sha256(f"prelude:{task['seed']}".encode()).hexdigest()
    return {"set": "prelude", "name": f"prelude-{task['name']}", "machine_seed": task["machine_seed"],
            "seed": int(digest[:8], 16) & 0x7FFFFFFF, "duration_s": PRELUDE_S, "faults": [],
            **({"_records": task["_records"]} if "_records" in task else {})}  # fmt: skip


def _make_prelude(config: dict[str, Any]) -> dict[str, Any]:
    """A task: the prelude's record made (or found) in the records folder."""
    plant_record(config)
    return {"path": str(record_path(config["_records"], config))}


def run_live(plan: BenchmarkPlan, seed: int, records: Path, out: Path, *, workers: int = 2,
             live: LivePlan | None = None, on_stage: Callable[[str], None] | None = None,
             on_progress: Callable[[int, int], None] | None = None) -> dict[str, Any]:  # fmt: skip
    """The live benchmark of ``plan`` (records kept in ``records``, the run's files in
    ``out``): results with the twin's scores beside the offline physics diagnosis's."""
    live = live or LivePlan()
    stage = on_stage or (lambda _: None)
    out.mkdir(parents=True, exist_ok=True)
    tasks = [{**t, "_records": str(records)} for t in task_configs(plan, seed)]
    stage("the benchmark's plant records (kept ones read back)")
    results = run_tasks(run_record, tasks, workers=workers)
    test = [(t, r) for t, r in zip(tasks, results, strict=True) if t["set"] != "tuning"]
    stage("the learning preludes (kept ones read back)")
    preludes = [{**prelude_config(t), "duration_s": live.prelude_s} for t, _ in test]
    made = run_tasks(_make_prelude, preludes, workers=workers)
    stage("the offline physics diagnosis of the same records")
    t0 = time.perf_counter()
    detector, offline_rows = physics_rows(tasks, results)
    offline_s = time.perf_counter() - t0
    tuning = [str(record_path(records, t)) for t in tasks if t["set"] == "tuning"]
    model, prior = _model_files(out, tuning)
    pairs = [(str(Path(m["path"]).resolve()), str(record_path(records, t).resolve()))
             for m, (t, _) in zip(made, test, strict=True)]  # fmt: skip
    lists = _deal_pairs(pairs, [t["duration_s"] for t, _ in test], live)
    playlist = out / "playlist.json"
    playlist.write_text(json.dumps({"machines": lists}, indent=1), encoding="utf-8")
    stage(f"serving {len(pairs)} machines' records on {len(lists)} slots at {live.speed:g}x")
    served = _serve(out, model, playlist, lists, live, on_progress)
    manifest = json.loads((out / "manifest.json").read_text(encoding="utf-8"))
    events = twin_events(out / "store")
    rows = live_rows(test, manifest, events, detector.reference_s)
    machine_s = sum(r["rows"] for s in manifest["machines"].values() for r in s) * 0.01
    plant = None
    if live.plant_machines:
        from drafttwin.studies.faults.live_plant import run_live_plant

        plant = run_live_plant(out, model, machines=live.plant_machines,
                               duration_s=live.plant_s, seed=seed, on_stage=stage)  # fmt: skip
    return {"benchmark": "faults-live", "plan": plan.name, "seed": seed, "plant": plant,
            "live": {"machines": live.machines, "speed": live.speed, "batch": live.batch,
                     "prelude_s": live.prelude_s,
                     "learn_s": live.prelude_s - LEARN_MARGIN_S, "transport": "mqtt", **served},
            "prior": {"file": prior.name, "fitted_on": len(tuning)},
            "machine_hours_served": machine_s / 3600.0,
            "offline": {"scores": score(offline_rows), "records": offline_rows,
                        "wall_s": offline_s},
            "twin": {"scores": score(rows), "records": rows},
            "events": _event_counts(events)}  # fmt: skip


def _deal_pairs(pairs: Sequence[tuple[str, str]], durations: Sequence[float],
                live: LivePlan) -> dict[str, list[str]]:  # fmt: skip
    """Each (prelude, record) pair to the slot with the least running so far."""
    slots: dict[str, list[str]] = {f"df-{k + 1:02d}": [] for k in range(live.machines)}
    load = dict.fromkeys(slots, 0.0)
    for (prelude, rec), dur in zip(pairs, durations, strict=True):
        name = min(load, key=lambda n: load[n])
        slots[name] += [prelude, rec]
        load[name] += live.prelude_s + dur + 2 * GAP_S
    return {k: v for k, v in slots.items() if v}


def _model_files(out: Path, tuning: Sequence[str]) -> tuple[Path, Path]:
    """The twin's model (the physics of the fa320a preset) and its detector file, fitted on
    the benchmark's tuning records: the prior each machine learns on."""
    model = out / "physics.dtm"
    run_command(cli_command("fit", "--model", "mechanistic", "--data", tuning[0], "--out", str(model),
                     "--quiet"))  # fmt: skip
    run_command(
        cli_command("twin", "fit-detector", "--model", str(model), "--healthy", ",".join(tuning))
    )
    return model, out / "physics.dtm.detector.json"


def _serve(out: Path, model: Path, playlist: Path, lists: dict[str, list[str]], live: LivePlan,
           on_progress: Callable[[int, int], None] | None) -> dict[str, Any]:  # fmt: skip
    """Broker, twin, replay; the replay played out and drained, the twin stopped (it ranks
    what its windows hold and stores every cause), the replay stopped."""
    mapping = out / "machines.toml"
    mapping.write_text("".join(f'[[machine]]\nname = "{n}"\n' for n in lists), encoding="utf-8")
    store = out / "store"
    if store.exists():
        shutil.rmtree(store)
    with broker() as port, contextlib.ExitStack() as stack:
        http = free_port()
        twin = stack.enter_context(child_process(cli_command(
            "twin", "run", "--model", str(model), "--source", f"mqtt://127.0.0.1:{port}",
            "--mapping", str(mapping), "--store", str(store), "--http", f"127.0.0.1:{http}",
            "--learn", f"{live.prelude_s - LEARN_MARGIN_S:g}", "--quiet"), out / "twin.log"))  # fmt: skip
        wait_live(http, twin, set(lists))
        started = time.perf_counter()
        replay = stack.enter_context(child_process(cli_command(
            "plant", "replay", "--playlist", str(playlist), "--mqtt", f"127.0.0.1:{port}",
            "--broker", "external", "--speed", f"{live.speed:g}", "--batch", str(live.batch),
            "--gap", f"{GAP_S:g}", "--manifest", str(out / "manifest.json"), "--hold"),
            out / "replay.log"))  # fmt: skip
        total = _rows_to_publish(lists)
        received = _drain(http, twin, replay, out / "manifest.json", total, on_progress)
        wall_s = time.perf_counter() - started
        status = twin_status(http)
        twin.send_signal(signal.SIGTERM)
        twin.wait(timeout=120)
        replay.send_signal(signal.SIGTERM)
        replay.wait(timeout=30)
    machines = (status or {}).get("machines", {})
    return {"wall_s": wall_s, "published": total, "received": received,
            "dropped": sum(m.get("dropped", 0) for m in machines.values()),
            "latency_ms": (status or {}).get("latency_ms"),
            "twin_exit": twin.returncode, "replay_exit": replay.returncode}  # fmt: skip


def _rows_to_publish(lists: dict[str, list[str]]) -> int:
    import pyarrow.parquet as pq

    return sum(pq.ParquetFile(f).metadata.num_rows for files in lists.values() for f in files)


def _drain(http: int, twin: subprocess.Popen[bytes], replay: subprocess.Popen[bytes],
           manifest: Path, total: int,
           on_progress: Callable[[int, int], None] | None) -> int:  # fmt: skip
    """Wait until the twin received every published sample (or stalled after the replay
    was out): the samples it received."""
    last, last_change = -1, time.monotonic()
    while True:
        for p, what in ((twin, "the twin"), (replay, "the replay")):
            if p.poll() is not None:
                raise RunError(f"{what} ended early (exit {p.returncode})",
                               source=manifest.parent / ("twin.log" if p is twin else "replay.log"))  # fmt: skip
        status = twin_status(http)
        got = sum(m["received"] for m in status["machines"].values()) if status else last
        if on_progress is not None:
            on_progress(got, total)
        if got != last:
            last, last_change = got, time.monotonic()
        out_done = manifest.exists()
        if got >= total or (out_done and time.monotonic() - last_change > STALL_S):
            return got
        time.sleep(1.0)


def _event_counts(events: Sequence[dict[str, Any]]) -> dict[str, int]:
    kinds: dict[str, int] = {}
    for e in events:
        kinds[e["kind"]] = kinds.get(e["kind"], 0) + 1
    return kinds


def live_rows(test: Sequence[tuple[dict[str, Any], dict[str, Any]]], manifest: dict[str, Any],
              events: Sequence[dict[str, Any]], reference_s: float) -> list[dict[str, Any]]:  # fmt: skip
    """Each test record's row from the twin's events: its alarms placed by the replay's
    manifest (source times back to record times) and the causes of the first at or after
    the onset, scored by :func:`~drafttwin.studies.faults.score.outcome`."""
    spans = {Path(e["file"]).name: (machine, e) for machine, played in manifest["machines"].items()
             for e in played}  # fmt: skip
    alarms: dict[str, list[tuple[float, str]]] = {}
    causes: dict[tuple[str, float], list[dict[str, Any]]] = {}
    for ev in events:
        if ev["kind"] not in ("fault", "sensor-fault", "fault-cause"):
            continue
        detail = json.loads(ev["detail"])
        key = (ev["machine"], round(float(detail["alarm_s"]), 3))
        if ev["kind"] == "fault-cause":
            causes[key] = detail.get("causes") or []
        else:
            alarms.setdefault(ev["machine"], []).append((float(detail["alarm_s"]), ev["kind"]))
            if ev["kind"] == "sensor-fault":  # named at once; its window sizes it later
                causes.setdefault(key, detail.get("causes") or [])
    rows = []
    for task, result in test:
        name = record_path(task["_records"], task).name
        machine, span = spans[name]
        t0 = float(result["raw"]["time_s"][0])
        to_record = t0 - float(span["start_s"])
        mine = [a for a, _ in alarms.get(machine, [])
                if span["start_s"] <= a <= span["end_s"] + 1e-6]  # fmt: skip
        label = result["labels"][0] if result["labels"] else None
        onset = onset_of(label)
        times = sorted(a + to_record for a in mine)
        top = None
        hits = [a for a in sorted(mine) if onset is not None and a + to_record >= onset]
        if hits:
            top = (hits[0] + to_record, causes.get((machine, round(hits[0], 3)), []))
        end = float(result["time_s"][-1])
        rows.append(outcome(task, label, onset, reference_s, end, times, top))
    return rows


def replayed_hours(manifest: dict[str, Any]) -> float:
    """Machine time the replay served, h."""
    spans = [e["end_s"] - e["start_s"] for v in manifest["machines"].values() for e in v]
    return float(np.sum(spans)) / 3600.0 if spans else math.nan


__all__ = ["LivePlan", "live_rows", "prelude_config", "replayed_hours", "run_live"]
