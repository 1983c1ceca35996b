"""The live benchmark's shorter run against the live plant itself: a few machines served by
``drafttwin plant serve`` (each its own process, machine seed and fault at a random time),
the twin watching them over MQTT at the wall clock, learning each first; scored as the
offline benchmark is, beside the offline diagnosis of the same machines and faults recorded
by the plant emulator (``Plant.run``): the emulator's two paths (recorded, served) and the
twin's two paths (offline, live) side by side.
"""

from __future__ import annotations

import contextlib
import json
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from drafttwin.errors import RunError
from drafttwin.studies.faults.harness import (
    LEARN_MARGIN_S,
    broker,
    child_process,
    cli_command,
    free_port,
    twin_events,
    twin_status,
    wait_live,
)
from drafttwin.studies.faults.plan import ELEMENTS, RATE_HZ
from drafttwin.studies.faults.score import outcome, score

LIVE_KINDS = ("bearing_friction", "load_loss", "belt_wear", "torque_loss", "wear", "elongation",
              "gain", "stuck", "dropout")  # fmt: skip
"""Fault kinds the live plant can inject (rotor resistance and eccentricity are drawn for a
whole record in advance)."""
LEARN_S = 120.0
REFERENCE_S = 15.0


def plant_cases(n: int, seed: int, duration_s: float) -> list[dict[str, Any]]:
    """``n`` machines, each with a moderate or severe fault of its own kind at a random time
    after its learning and reference window (at least a minute of watched healthy running
    before it, half a minute after it)."""
    from drafttwin.plant.fault_cases import make_fault

    rng = np.random.default_rng(seed)
    kinds = rng.permutation(LIVE_KINDS)
    first = LEARN_S + LEARN_MARGIN_S + REFERENCE_S + 60.0
    cases = []
    for k in range(n):
        kind = str(kinds[k % len(kinds)])
        level = int(rng.integers(1, 3))
        element = ELEMENTS[kind][level % len(ELEMENTS[kind])]
        onset = float(np.round(rng.uniform(first, duration_s - 30.0), 2))
        sign = 1.0 if rng.random() < 0.5 else -1.0
        f = make_fault(element, kind, level, True, onset, duration_s, sign)
        spec = f"{f.element}:{f.kind}:severity={f.severity:g}:onset={f.onset_s:g}"
        cases.append({"set": "faults", "name": f"dfp-{k + 1:02d}", "machine_seed": int(rng.integers(0, 2**31)),
                      "seed": int(rng.integers(0, 2**31)), "level": level, "profile": "step",
                      "fault": spec, "faults": [f.model_dump()], "duration_s": duration_s,
                      "label": {"element": element, "kind": kind, "family": _family(kind),
                                "severity": f.severity, "onset_s": onset}})  # fmt: skip
    return cases


def _family(kind: str) -> str:
    from drafttwin.mechanics.faults import KINDS

    return str(KINDS[kind].family)


def run_live_plant(out: Path, model: Path, *, machines: int = 4, duration_s: float = 600.0,
                   seed: int = 0, on_stage: Callable[[str], None] | None = None) -> dict[str, Any]:  # fmt: skip
    """Serve ``machines`` live plants for ``duration_s`` (wall clock) to the twin of ``model``
    (its detector file the prior); score the twin's alarms beside the offline diagnosis of
    the same machines and faults recorded."""
    stage = on_stage or (lambda _: None)
    out.mkdir(parents=True, exist_ok=True)
    cases = plant_cases(machines, seed, duration_s)
    mapping = out / "plant_machines.toml"
    mapping.write_text("".join(f'[[machine]]\nname = "{c["name"]}"\n' for c in cases),
                       encoding="utf-8")  # fmt: skip
    store = out / "plant_store"
    stage(f"{machines} live plants for {duration_s / 60:.0f} min, faults at random times")
    with broker() as port, contextlib.ExitStack() as stack:
        http = free_port()
        twin = stack.enter_context(child_process(cli_command(
            "twin", "run", "--model", str(model), "--source", f"mqtt://127.0.0.1:{port}",
            "--mapping", str(mapping), "--store", str(store), "--http", f"127.0.0.1:{http}",
            "--learn", f"{LEARN_S:g}", "--quiet"), out / "plant_twin.log"))  # fmt: skip
        wait_live(http, twin, {c["name"] for c in cases})
        plants = [
            stack.enter_context(
                child_process(
                    cli_command(
                        "plant",
                        "serve",
                        "--mqtt",
                        f"127.0.0.1:{port}",
                        "--broker",
                        "external",
                        "--name",
                        c["name"],
                        "--seed",
                        str(c["machine_seed"]),
                        "--fault",
                        c["fault"],
                        "--duration",
                        f"{duration_s:g}",
                        "--log",
                        str(out / f"{c['name']}.log.parquet"),
                    ),
                    out / f"{c['name']}.log",
                )
            )  # fmt: skip
            for c in cases
        ]
        for p in plants:
            p.wait(timeout=duration_s + 300)
            if p.returncode != 0:
                raise RunError(f"a plant ended with exit {p.returncode}", source=out)
        time.sleep(3.0)  # the last samples reach the twin
        status = twin_status(http)
        twin.send_signal(signal.SIGTERM)
        twin.wait(timeout=120)
    events = twin_events(store)
    rows = _plant_rows(cases, events, out)
    stage("the same machines and faults recorded, diagnosed offline")
    offline = _recorded_rows(cases, model)
    machines_status = (status or {}).get("machines", {})
    return {"machines": machines, "duration_s": duration_s, "seed": seed,
            "cases": [{k: c[k] for k in ("name", "machine_seed", "fault")} for c in cases],
            "received": sum(m.get("received", 0) for m in machines_status.values()),
            "dropped": sum(m.get("dropped", 0) for m in machines_status.values()),
            "twin": {"scores": score(rows), "records": rows},
            "offline": {"scores": score(offline), "records": offline}}  # fmt: skip


def _plant_rows(cases: list[dict[str, Any]], events: list[dict[str, Any]],
                out: Path) -> list[dict[str, Any]]:  # fmt: skip
    """Each served machine's row: alarms in plant time (seconds from its start, from its own
    log), the causes of the first at or after the onset."""
    from drafttwin.wire.plantlog import read_plant_log

    rows = []
    for c in cases:
        log = read_plant_log(out / f"{c['name']}.log.parquet")
        first_us = int(log["ts_us"].min())
        first_seq = int(log["seq"].min())
        t0 = first_us / 1e6 - (first_seq - 1) / RATE_HZ  # the plant's start, epoch s
        mine = [e for e in events if e["machine"] == c["name"]]
        alarms, causes = [], {}
        for e in mine:
            if e["kind"] not in ("fault", "sensor-fault", "fault-cause"):
                continue
            d = json.loads(e["detail"])
            t = float(d["alarm_s"]) - t0
            if e["kind"] == "fault-cause":
                causes[round(t, 2)] = d.get("causes") or []
            else:
                alarms.append(t)
                if e["kind"] == "sensor-fault":
                    causes.setdefault(round(t, 2), d.get("causes") or [])
        label = c["label"]
        hits = sorted(a for a in alarms if a >= label["onset_s"])
        top = (hits[0], causes.get(round(hits[0], 2), [])) if hits else None
        start = LEARN_S + LEARN_MARGIN_S + REFERENCE_S
        end = float(log["ts_us"].max()) / 1e6 - t0
        rows.append(outcome(c, label, label["onset_s"], start, end, sorted(alarms), top))
    return rows


def _recorded_rows(cases: list[dict[str, Any]], model: Path) -> list[dict[str, Any]]:
    """The same machines and faults recorded by the emulator and diagnosed offline with the
    model's detector file (its physics, its thresholds)."""
    from drafttwin.diagnosis.detect import FaultDetector
    from drafttwin.diagnosis.diagnose import Diagnoser
    from drafttwin.diagnosis.residuals import record_features
    from drafttwin.diagnosis.stream import decide
    from drafttwin.mechanics import DriveTrain
    from drafttwin.plant import Machine, Plant
    from drafttwin.plant.faults import FaultSpec

    doc = json.loads(model.with_name(model.name + ".detector.json").read_text(encoding="utf-8"))
    det = FaultDetector.from_state(doc["detector"])
    train = DriveTrain.preset("fa320a")
    dx = Diagnoser(train, det)
    plant = Plant()
    rows = []
    for c in cases:
        rec = plant.run(c["duration_s"], RATE_HZ, seed=c["seed"],
                        machine=Machine.draw(plant.train, plant.config, c["machine_seed"]),
                        faults=[FaultSpec(**f) for f in c["faults"]])  # fmt: skip
        f = record_features(train, rec.series)
        alarms = [a.time_s for a in decide(det, f)[0].alarms]
        label = {**c["label"], **(rec.info["faults"][0] if rec.info["faults"] else {})}
        onset = label.get("effective_onset_s", label["onset_s"])
        d = dx.from_features(f, onset)
        top = None
        if d.alarm is not None and d.causes:
            top = (d.alarm.time_s, [{"element": x.element, "kind": x.kind, "family": x.family,
                                     "severity": x.severity, "group": list(x.group)}
                                    for x in d.causes[:3]])  # fmt: skip
        rows.append(outcome(c, label, onset, det.reference_s, float(f.time_s[-1]), alarms, top))
    return rows


__all__ = ["LIVE_KINDS", "plant_cases", "run_live_plant"]
