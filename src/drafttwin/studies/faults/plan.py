"""What the fault benchmark runs: seeded records of the plant, each a task.

Three sets, each of its own machines and recording seeds (none shared):

* ``tuning``: healthy records that set the thresholds (and nothing else); as long as the
  healthy test records in the full plan, so the slow wander of a 10-min run (its long-run
  variance, :class:`~drafttwin.diagnosis.detect.FaultDetector`) is in them;
* ``faults``: one record per fault kind x severity level x profile (abrupt step, or an
  incipient ramp), the element cycling through :data:`ELEMENTS`;
* ``healthy``: healthy running of several machines, for false alarms.

A task runs the plant and returns the record's block features against the physics (the
``fa320a`` preset: a nominal twin, not calibrated to each machine) and its labels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from drafttwin.diagnosis.detect import FaultDetector
from drafttwin.diagnosis.residuals import (
    block_features,
    measured,
    physics_prediction,
    roller_ratio,
)
from drafttwin.mechanics import DriveTrain
from drafttwin.plant import Machine, Plant
from drafttwin.plant.fault_cases import make_fault
from drafttwin.studies.faults.learned import raw_record

ELEMENTS: dict[str, tuple[str, ...]] = {
    "crack": ("E-F", "G-H", "A-B"), "wear": ("E-F", "G-H", "I-J"),
    "runout": ("A-B", "G-H", "E-F"), "belt_wear": ("main_belt",),
    "elongation": ("rear_chain",), "bearing_friction": ("front_roller", "motor", "back_roller"),
    "load_loss": ("front", "third", "back"), "eccentricity": ("second", "front", "back"),
    "rotor_resistance": ("motor",), "torque_loss": ("motor",),
    "gain": ("third", "motor", "front"), "stuck": ("back", "second", "motor"),
    "dropout": ("front", "motor", "third"),
}  # fmt: skip
QUICK_KINDS = ("bearing_friction", "load_loss", "belt_wear", "rotor_resistance", "gain", "stuck")
RATE_HZ = 100.0
BLOCK_S = 1.0
HEALTHY_RECORD_S = 630.0
"""Healthy test records of the full plan: 10.5 min each, so that 12 machines give the
issue's >= 2 h of running after each record's reference window (15 s: no decisions there)."""


@dataclass(frozen=True)
class BenchmarkPlan:
    """What one benchmark run holds: kinds, severities, fault profiles (step, ramp) and the
    sizes of the three record sets (not to be confused with a model profile)."""

    name: str
    kinds: tuple[str, ...]
    levels: tuple[int, ...]  # 0 light, 1 moderate, 2 severe
    profiles: tuple[str, ...]  # step, ramp
    duration_s: float  # fault records
    onset_s: tuple[float, float]  # onset drawn in this range
    ramp_s: float
    tuning: tuple[int, float]  # records, seconds each
    healthy: tuple[int, float]


PLANS = {
    "full": BenchmarkPlan("full", tuple(ELEMENTS), (0, 1, 2), ("step", "ramp"), 40.0, (18.0, 22.0),
                    10.0, (4, HEALTHY_RECORD_S), (12, HEALTHY_RECORD_S)),
    "quick": BenchmarkPlan("quick", QUICK_KINDS, (1,), ("step",), 30.0, (18.0, 20.0), 5.0,
                     (2, 40.0), (2, 60.0)),
}  # fmt: skip


def decided_s(duration_s: float) -> float:
    """Seconds of a healthy record that are watched: those after the reference window."""
    return max(0.0, duration_s - FaultDetector().reference_s)


REDUCED_HZ = 200.0
"""Cut-off (Hz) of a task's reduced plant (``"generator": "reduced"``): every coupling but
the belt rigid. Not a stand-in for the full plant's healthy running: it misses the detector's
statistics (:mod:`drafttwin.studies.faults.generator`, docs/faults.md)."""


def with_healthy_hours(plan: BenchmarkPlan, hours: float) -> BenchmarkPlan:
    """``plan`` with at least ``hours`` of watched healthy running (records of the plan's
    healthy length, each its own machine)."""
    per = decided_s(plan.healthy[1])
    return replace(plan, healthy=(max(1, math.ceil(hours * 3600.0 / per)), plan.healthy[1]))


def task_configs(plan: BenchmarkPlan, seed: int) -> list[dict[str, Any]]:
    """Task configurations (JSON-able): tuning, then fault, then healthy records."""
    rng = np.random.default_rng(seed)

    def seeds() -> tuple[int, int]:
        a, b = (int(x) for x in rng.integers(0, 2**31, size=2))
        return a, b

    tasks: list[dict[str, Any]] = []
    for i in range(plan.tuning[0]):
        m, s = seeds()
        tasks.append({"set": "tuning", "name": f"tuning_{i}", "machine_seed": m, "seed": s,
                      "duration_s": plan.tuning[1], "faults": []})  # fmt: skip
    for kind in plan.kinds:
        for level in plan.levels:
            for prof in plan.profiles:
                m, s = seeds()
                onset = float(np.round(rng.uniform(*plan.onset_s), 2))
                element = ELEMENTS[kind][level % len(ELEMENTS[kind])]
                sign = 1.0 if rng.random() < 0.5 else -1.0
                f = make_fault(element, kind, level, prof == "step", onset, plan.duration_s, sign)
                if prof == "ramp" and f.ramp_s > 0:
                    f = f.model_copy(update={"ramp_s": plan.ramp_s})
                tasks.append({"set": "faults", "name": f"{element}:{kind}:{level}:{prof}",
                              "machine_seed": m, "seed": s, "duration_s": plan.duration_s,
                              "level": level, "profile": prof,
                              "faults": [f.model_dump()]})  # fmt: skip
    for i in range(plan.healthy[0]):
        m, s = seeds()
        tasks.append({"set": "healthy", "name": f"healthy_{i}", "machine_seed": m, "seed": s,
                      "duration_s": plan.healthy[1], "faults": []})  # fmt: skip
    return tasks


def plant_record(config: dict[str, Any]) -> tuple[Any, list[dict[str, Any]]]:
    """The task's plant record (its series) and fault labels: read from the records folder
    ``config["_records"]`` when kept there (:mod:`.records`), else made (and kept there). The
    full plant, or with ``config["generator"] == "reduced"`` the reduced one (healthy records
    only; :mod:`drafttwin.studies.faults.generator` compares them)."""
    from drafttwin.plant.faults import FaultSpec
    from drafttwin.studies.faults.records import load_record, record_path, save_record

    folder = config.get("_records")
    path = None if folder is None else record_path(folder, config)
    if path is not None and (kept := load_record(path)) is not None:
        return kept
    plant = Plant(reduced_hz=REDUCED_HZ if config.get("generator") == "reduced" else None)
    machine = Machine.draw(plant.train, plant.config, int(config["machine_seed"]))
    faults = [FaultSpec(**f) for f in config["faults"]]
    rec = plant.run(float(config["duration_s"]), RATE_HZ, seed=int(config["seed"]),
                    machine=machine, faults=faults)  # fmt: skip
    labels = list(rec.info["faults"])
    if path is not None:
        save_record(path, config, rec.series, labels)
    return rec.series, labels


def run_record(config: dict[str, Any]) -> dict[str, Any]:
    """One task: the plant record's physics block features and labels (plain lists), and
    its raw channels with the physics prediction (arrays) for the learned residuals."""
    series, labels = plant_record(config)
    train = DriveTrain.preset("fa320a")
    physics = physics_prediction(train, series)
    f = block_features(measured(series), physics, series.time_s, BLOCK_S, roller_ratio(train))
    return {"time_s": f.time_s.tolist(), "level": f.level.tolist(), "lost": f.lost.tolist(),
            "run": f.run.tolist(), "stale": f.stale_runs.tolist(), "block_s": f.block_s,
            "lag": f.lags.tolist(),
            "labels": labels, "raw": raw_record(series, physics)}  # fmt: skip
