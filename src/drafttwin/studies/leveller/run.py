"""The leveller benchmark: plan, one case, the whole run and its summary.

One case is one seeded plant machine (its true drive train at 2 kHz), one feed fault and one
leveller fault (a wrong action point always; a sluggish drive or a drifting infeed sensor in
the fault cases). Everything a case drafts uses the same fibres (the record's seed), so the
CV against the action point is a smooth curve and its minimum is found by Brent's method
(bounded, 0.5 mm), each evaluation a full drafting of every fibre.
"""

from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import minimize_scalar

from drafttwin.plant import Machine, Plant
from drafttwin.plant.sliver_channel import (
    SURFACE_RATE_HZ,
    SliverChannel,
    SliverSettings,
    default_feed,
    make_sliver,
)
from drafttwin.sliver import FeedFault
from drafttwin.sliver.action_point import find_action_point
from drafttwin.sliver.irregularity import evenness
from drafttwin.sliver.leveller import NOMINAL_DRIVE_S, Autoleveller, InfeedSensor, RegulatingDrive
from drafttwin.sliver.leveller_record import LevellerRecord, LevellerSetting

CASE_KINDS = ("long-wave", "missing", "piecing")
"""The feed faults, in turn over the cases."""
FAULT_KINDS = ("sluggish-drive", "infeed-drift")
"""The leveller faults of the fault cases, in turn."""
DELIVERY_M_S = 256.61 / 60.0
"""The FA320A's delivery speed, m/s (a record's length over its duration)."""
SLUGGISH_DRIVE_S = 0.04
"""A sluggish regulating drive's time constant, s (8 x the nominal)."""
INFEED_DRIFT_PCT_PER_MIN = 0.5
"""A drifting infeed sensor's gain drift, % per minute."""
BRUTE_BOUNDS_MM = (-70.0, 30.0)
"""Action points searched for the CV minimum, mm from the true one."""
TOLERANCE_MM, TOLERANCE_CV = 5.0, 0.05
"""The done-when: within 5 mm of the CV minimum, a CV within 5 % of it."""
SHORT_M = (25.0, 50.0, 100.0)
"""Shorter heads of each record the recommendation is also made from, m."""


@dataclass(frozen=True)
class LevellerBenchConfig:
    """The benchmark's plan.

    Attributes:
        machines: cases with the leveller at a wrong action point (the done-when's).
        fault_cases: cases with a sluggish drive or a drifting infeed sensor, in turn.
        seed: draws the machines, feed faults and settings.
        length_m: delivered sliver per record, m (at most).
        fibre_scale: fibres lumped into one (1: every fibre; the quick run lumps 8).
        xatol_mm: precision of the CV minimum's search, mm.
    """

    machines: int = 10
    fault_cases: int = 4
    seed: int = 0
    length_m: float = 300.0
    fibre_scale: float = 1.0
    xatol_mm: float = 0.5

    @classmethod
    def quick(cls, seed: int = 0) -> LevellerBenchConfig:
        return cls(machines=2, fault_cases=0, seed=seed, length_m=80.0, fibre_scale=8.0,
                   xatol_mm=2.0)  # fmt: skip


def plan(config: LevellerBenchConfig) -> list[dict[str, Any]]:
    """One task per case: machine, feed fault, leveller setting and fault (seeded)."""
    rng = np.random.default_rng(np.random.SeedSequence([39, config.seed]))
    fed_m = config.length_m / 6.57  # fed sliver of a record, m
    tasks = []
    for k in range(config.machines + config.fault_cases):
        fault = None if k < config.machines else FAULT_KINDS[(k - config.machines) % 2]
        kind = CASE_KINDS[k % len(CASE_KINDS)]
        sign = 1.0 if rng.random() < 0.5 else -1.0
        offset = sign * rng.uniform(15.0, 40.0) if fault is None else sign * rng.uniform(0, 10)
        feed: dict[str, Any] = {"kind": kind}
        if kind == "long-wave":
            feed |= {"wavelength_m": float(rng.uniform(1.0, 5.0)),
                     "amplitude": float(rng.uniform(0.02, 0.05))}  # fmt: skip
        elif kind == "missing":
            start = float(rng.uniform(0.15, 0.45) * fed_m)
            feed |= {"from_m": start, "to_m": start + float(rng.uniform(0.1, 0.3) * fed_m)}
        else:
            feed |= {"at_m": sorted(float(x) for x in rng.uniform(0.15, 0.95, 3) * fed_m)}
        tasks.append({
            "case": k, "machine_seed": 3900 + 100 * config.seed + k, "record_seed": k + 1,
            "feed": feed, "offset_mm": round(float(offset), 1), "leveller_fault": fault,
            "length_m": config.length_m, "fibre_scale": config.fibre_scale,
            "xatol_mm": config.xatol_mm,
        })  # fmt: skip
    return tasks


def _feed(spec: dict[str, Any]) -> Any:
    feed = default_feed()
    if spec["kind"] == "long-wave":
        return default_feed((FeedFault(spec["wavelength_m"], spec["amplitude"], "all"),))
    if spec["kind"] == "missing":
        return replace(feed, runs_out_m=(spec["from_m"], spec["to_m"]))
    return replace(feed, piecings_m=tuple(spec["at_m"]))


def _channel_record(ch: SliverChannel) -> LevellerRecord:
    d = ch.delivery
    assert d.time_s is not None
    return LevellerRecord(d.delivered_length_m, d.linear_density_ktex, ch.infeed_ktex,
                          ch.fed_length_m, d.time_s)  # fmt: skip


def run_case(task: dict[str, Any]) -> dict[str, Any]:
    """One case: the record at the wrong setting, the recommendation from it, the simulated
    CV minimum over the action point, and the CV the recommendation reaches."""
    start = time.perf_counter()
    plant = Plant()
    machine = Machine.draw(plant.train, plant.config, task["machine_seed"])
    duration = math.floor(task["length_m"] / DELIVERY_M_S * 10) / 10
    rec = plant.run(duration, 100.0, seed=task["record_seed"], machine=machine,
                    surface_rate_hz=SURFACE_RATE_HZ)  # fmt: skip
    assert rec.surface is not None
    surface = rec.surface
    fault = task["leveller_fault"]
    sensor = InfeedSensor(
        drift_pct_per_min=INFEED_DRIFT_PCT_PER_MIN if fault == "infeed-drift" else 0.0
    )
    drive = RegulatingDrive(SLUGGISH_DRIVE_S if fault == "sluggish-drive" else NOMINAL_DRIVE_S)
    settings = SliverSettings(feed=_feed(task["feed"]), infeed=sensor,
                              fibre_scale=task["fibre_scale"])  # fmt: skip
    seed = task["record_seed"]

    def draft_at(offset_mm: float, intensity: float = 1.0) -> SliverChannel:
        lev = Autoleveller(intensity, offset_mm, sensor=sensor, drive=drive)
        return make_sliver(surface.time_s, surface.length_m, replace(settings, leveller=lev),
                           np.random.default_rng(seed), seed)  # fmt: skip

    def cv_pct(ch: SliverChannel) -> float:
        return evenness(ch.true.linear_density_ktex, ch.true.step_m).cv_pct

    record = draft_at(task["offset_mm"])
    lev = record.summary["leveller"]
    true_mm = float(lev["true_action_point_mm"])
    setting = LevellerSetting(
        float(lev["action_point_mm"]), 1.0, settings.feed.total_ktex, NOMINAL_DRIVE_S
    )  # the machine knows its drive's nominal only
    readings = _channel_record(record)
    advice = find_action_point(readings, setting, settings.feed.staple, settings.delivery)
    shorter = {length: find_action_point(readings.head(length), setting, settings.feed.staple,
                                         settings.delivery)
               for length in SHORT_M if length < readings.length_m}  # fmt: skip
    evaluations: dict[float, float] = {}

    def cv_at(offset_mm: float) -> float:
        if offset_mm not in evaluations:
            evaluations[offset_mm] = cv_pct(draft_at(offset_mm))
        return evaluations[offset_mm]

    best = minimize_scalar(cv_at, bounds=BRUTE_BOUNDS_MM, method="bounded",
                           options={"xatol": task["xatol_mm"]})  # fmt: skip
    brute_offset, brute_cv = float(best.x), float(best.fun)
    rec_offset = advice.recommended_action_point_mm - true_mm
    reached = cv_pct(draft_at(rec_offset, advice.recommended_intensity))
    reached_i1 = cv_at(rec_offset)
    return {
        **{k: task[k] for k in ("case", "machine_seed", "record_seed", "feed", "offset_mm",
                                "leveller_fault", "length_m")},
        "true_action_point_mm": true_mm,
        "setting_mm": setting.action_point_mm,
        "record_m": record.delivery.length_m,
        "record_cv_pct": cv_pct(record),
        "advice": advice.to_dict(),
        "brute_min_action_point_mm": true_mm + brute_offset,
        "brute_min_cv_pct": brute_cv,
        "brute_evaluations": len(evaluations),
        "brute_curve": sorted((true_mm + k, v) for k, v in evaluations.items()),
        "reached_cv_pct": reached,
        "reached_cv_at_intensity_1_pct": reached_i1,
        "error_mm": advice.recommended_action_point_mm - (true_mm + brute_offset),
        "cv_ratio": reached / brute_cv,
        "within_mm": abs(advice.recommended_action_point_mm - (true_mm + brute_offset)) <= TOLERANCE_MM,
        "within_cv": reached <= (1 + TOLERANCE_CV) * brute_cv,
        "shorter": [{"length_m": length, "recommended_action_point_mm":
                     a.recommended_action_point_mm,
                     "action_point_interval_mm": list(a.action_point_interval_mm),
                     "error_mm": a.recommended_action_point_mm - (true_mm + brute_offset)}
                    for length, a in shorter.items()],
        "wall_s": time.perf_counter() - start,
    }  # fmt: skip


def summarise(cases: list[dict[str, Any]]) -> dict[str, Any]:
    """Counts of the done-when over the wrong-action-point cases, and the fault cases apart."""
    out: dict[str, Any] = {}
    for group, rows in (("wrong action point", [c for c in cases if not c["leveller_fault"]]),
                        *((f, [c for c in cases if c["leveller_fault"] == f])
                          for f in FAULT_KINDS)):  # fmt: skip
        if not rows:
            continue
        out[group] = {
            "cases": len(rows),
            "within_5_mm": sum(c["within_mm"] for c in rows),
            "within_5_pct_cv": sum(c["within_cv"] for c in rows),
            "both": sum(c["within_mm"] and c["within_cv"] for c in rows),
            "median_abs_error_mm": float(np.median([abs(c["error_mm"]) for c in rows])),
            "max_abs_error_mm": float(max(abs(c["error_mm"]) for c in rows)),
            "max_cv_ratio": float(max(c["cv_ratio"] for c in rows)),
            "max_metres_used": float(max(c["advice"]["metres_used"] for c in rows)),
            "shorter_within_5_mm": _shorter(rows),
        }  # fmt: skip
    return out


def _shorter(rows: list[dict[str, Any]]) -> dict[str, list[int]]:
    """Per head length: [cases within 5 mm of the CV minimum, cases with such a head]."""
    out = {}
    for length in SHORT_M:
        heads = [h for c in rows for h in c["shorter"] if h["length_m"] == length]
        if heads:
            out[f"{length:g} m"] = [sum(abs(h["error_mm"]) <= TOLERANCE_MM for h in heads),
                                    len(heads)]  # fmt: skip
    return out


def code_digest() -> str:
    """A hash of the code a case runs (the sliver, the plant and this study): cached cases of
    other code are not reused."""
    import drafttwin.plant
    import drafttwin.sliver

    h = hashlib.sha256()
    for package in (drafttwin.sliver, drafttwin.plant):
        for path in sorted(Path(package.__path__[0]).rglob("*.py")):
            h.update(path.read_bytes())
    h.update(Path(__file__).read_bytes())
    return h.hexdigest()[:16]


def run_benchmark(config: LevellerBenchConfig, workers: int = 1, cache: Path | None = None,
                  on_case: Callable[[int, int], None] | None = None) -> dict[str, Any]:  # fmt: skip
    """All cases (``workers`` processes; finished cases kept in ``cache`` and not run again
    by the same code) and their summary."""
    from drafttwin.execution import ResultStore, run_tasks

    tasks = plan(config)
    done = [0]

    def tick(i: int, result: dict[str, Any], cached: bool) -> None:
        done[0] += 1
        if on_case is not None:
            on_case(done[0], len(tasks))

    store = ResultStore(cache) if cache is not None else None
    cases = run_tasks(run_case, tasks, workers=workers, on_result=tick, store=store,
                      data_digest=code_digest())  # fmt: skip
    return {"config": asdict(config), "cases": cases, "summary": summarise(cases)}
