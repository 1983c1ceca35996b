"""Scoring of the fault benchmark, as fault-diagnosis benchmarks do (DAMADICS, CARE).

Per method: detection rate per severity level (an alarm at or after the fault's effective
onset; the alarms as the live twin raises them, :func:`~drafttwin.diagnosis.stream.decide`),
median and 90th-percentile delay of abrupt faults (misses counted beside them),
false alarms per 24 h over all fault-free running (healthy records and the time before each
onset, after the reference window) with a Poisson 95 % upper bound, top-1 and top-3
localisation of the first alarm at or after the onset (element and kind), the group hit (the truth inside the first cause's group of
look-alikes), median relative severity error of correct top-1 answers, sensor faults blamed
on a machine element, and a confusion matrix of true kind against the first cause's kind.

Methods (all thresholds from the same healthy tuning records, the same false-alarm budget):
``physics`` (open-loop physics residual, whitened CUSUM, model-based ranking with the
model-mismatch term of the belt creep; the same without it is scored beside), ``hybrid``
(the parallel hybrid's open-loop residual, the same detector and ranking), ``data-driven``
(the one-step GRU's residual, the same detector; not localised) and ``raw-threshold`` (each
channel's raw block speed against its record's reference; no localisation). The learned
residuals are in :mod:`drafttwin.studies.faults.learned`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.stats import chi2, norm

from drafttwin.diagnosis.detect import FaultDetector
from drafttwin.diagnosis.diagnose import Diagnoser
from drafttwin.diagnosis.locate import NOT_ASSESSED
from drafttwin.diagnosis.residuals import BlockFeatures
from drafttwin.diagnosis.stream import decide
from drafttwin.plant.faults import KINDS

LEVEL_NAMES = ("light", "moderate", "severe")
NOMINAL = "physics, no mismatch term"
METHODS = ("physics", NOMINAL, "hybrid", "data-driven", "raw-threshold")
LOCATED = ("physics", "hybrid")  # the methods whose residual shift the physics ranking explains


NETWORK_FIT_S = 60.0


def _head(raw: dict[str, Any], seconds: float) -> dict[str, Any]:
    """The first ``seconds`` of a raw record (every array cut alike)."""
    t = np.asarray(raw["time_s"])
    n = int(np.searchsorted(t, t[0] + seconds))
    return {k: np.asarray(v)[:n] for k, v in raw.items()}


def features(result: dict[str, Any]) -> BlockFeatures:
    lag, stale = result.get("lag"), result.get("stale")
    return BlockFeatures(np.asarray(result["time_s"]), np.asarray(result["level"], dtype=float),
                         np.asarray(result["lost"]), np.asarray(result["run"]),
                         float(result["block_s"]),
                         None if lag is None else np.asarray(lag, dtype=float),
                         None if stale is None else np.asarray(stale, dtype=float))  # fmt: skip


class RawThreshold:
    """Baseline: fixed +-z sigma thresholds on each channel's raw block speed deviation from
    its record's reference window, z set for the false-alarm budget (Gaussian, per block)."""

    def __init__(self, far_per_day: float, reference_s: float) -> None:
        self.far_per_day, self.reference_s = far_per_day, reference_s

    def fit(self, healthy: Sequence[BlockFeatures]) -> RawThreshold:
        devs = np.vstack([self._dev(f) for f in healthy])
        self.sigma_ = np.nanstd(devs, axis=0)
        blocks_per_day = 86400.0 / healthy[0].block_s
        p = self.far_per_day / (blocks_per_day * devs.shape[1])
        self.z_ = float(norm.isf(p / 2))
        return self

    def _dev(self, f: BlockFeatures) -> np.ndarray:
        n_ref = max(2, int(round(self.reference_s / f.block_s)))
        dev: np.ndarray = f.level[n_ref:] - np.nanmean(f.level[:n_ref], axis=0)
        return dev

    def alarm_times(self, f: BlockFeatures) -> list[float]:
        """Start times of alarm episodes (consecutive alarming blocks are one episode)."""
        n_ref = max(2, int(round(self.reference_s / f.block_s)))
        with np.errstate(invalid="ignore"):
            hit = (np.abs(self._dev(f)) > self.z_ * self.sigma_).any(axis=1)
        t = f.time_s[n_ref:]
        starts = hit & ~np.concatenate([[False], hit[:-1]])
        return [float(x) for x in t[starts]]


def poisson_upper(count: int, hours: float) -> float:
    """95 % upper bound of a rate per 24 h from ``count`` events in ``hours``."""
    if hours <= 0:
        return math.inf
    return float(chi2.ppf(0.95, 2 * count + 2) / 2 / hours * 24)


def score_records(tasks: Sequence[dict[str, Any]], results: Sequence[dict[str, Any]],
             far_per_day: float = 1.0, seed: int = 0) -> dict[str, Any]:  # fmt: skip
    """Fit on the tuning set, run every method on the rest, score them."""
    from drafttwin.mechanics import DriveTrain
    from drafttwin.studies.faults.learned import LEARNED, LearnedResiduals

    tuning = [t["set"] == "tuning" for t in tasks]
    physics = [features(r) for r in results]
    learned = LearnedResiduals(physics[0].block_s, seed)
    # the networks learn from each tuning record's first minute (as they did when the
    # records were 1 min long); the long records set the detectors' thresholds
    learned.fit(
        [_head(r["raw"], NETWORK_FIT_S) for r, tu in zip(results, tuning, strict=True) if tu]
    )
    feats = {"physics": physics, **{m: [learned.features(m, r["raw"], p)
                                        for r, p in zip(results, physics, strict=True)]
                                    for m in LEARNED}}  # fmt: skip
    dets = {m: FaultDetector(far_per_day=far_per_day).fit([f for f, tu in zip(fs, tuning, strict=True) if tu])
            for m, fs in feats.items()}  # fmt: skip
    start = dets["physics"].reference_s
    raw = RawThreshold(far_per_day, start).fit(
        [f for f, tu in zip(physics, tuning, strict=True) if tu]
    )
    train = DriveTrain.preset("fa320a")
    located = {m: Diagnoser(train, dets[m]) for m in LOCATED}
    # the same physics diagnosis without the model-mismatch term, for comparison
    located[NOMINAL] = Diagnoser(train, dets["physics"], model_mismatch=False)
    rows: dict[str, list[dict[str, Any]]] = {m: [] for m in METHODS}
    for i, (t, r) in enumerate(zip(tasks, results, strict=True)):
        if tuning[i]:
            continue
        label = r["labels"][0] if r["labels"] else None
        onset = onset_of(label)
        for m, fs in feats.items():
            f = fs[i]
            # the alarms as the live twin raises them (one stream of decisions; a sensor rule
            # once per episode), the causes of the first at or after the onset
            alarms = [a.time_s for a in decide(dets[m], f)[0].alarms]
            dx = located[m].from_features(f, onset) if label and m in located else None
            rows[m].append(_outcome(t, label, onset, start, f, alarms, dx))
            if m == "physics":
                dx = located[NOMINAL].from_features(f, onset) if label else None
                rows[NOMINAL].append(_outcome(t, label, onset, start, f, alarms, dx))
        rows["raw-threshold"].append(_outcome(t, label, onset, start, physics[i],
                                              raw.alarm_times(physics[i]), None))  # fmt: skip
    return {"detectors": {m: d.describe() for m, d in dets.items()}, "learned": learned.describe(),
            "creep_rel_sd": {m: located[m].creep_rel_sd for m in LOCATED},
            "raw_threshold": {"z": raw.z_, "sigma": raw.sigma_.tolist()}, "records": rows,
            "scores": {m: score(v) for m, v in rows.items()}}  # fmt: skip


def onset_of(label: dict[str, Any] | None) -> float | None:
    """A fault's effective onset (record time, s); ``None`` for a healthy record."""
    return None if label is None else label.get("effective_onset_s", label["onset_s"])


def physics_rows(tasks: Sequence[dict[str, Any]], results: Sequence[dict[str, Any]],
                 far_per_day: float = 1.0) -> tuple[FaultDetector, list[dict[str, Any]]]:  # fmt: skip
    """The physics diagnosis alone (thresholds from the tuning records) on every other record:
    its detector and rows, as :func:`score_records` makes them (the live benchmark prints the
    twin's beside them)."""
    from drafttwin.mechanics import DriveTrain

    feats = [features(r) for r in results]
    det = FaultDetector(far_per_day=far_per_day).fit(
        [f for f, t in zip(feats, tasks, strict=True) if t["set"] == "tuning"]
    )
    dx = Diagnoser(DriveTrain.preset("fa320a"), det)
    rows = []
    for t, r, f in zip(tasks, results, feats, strict=True):
        if t["set"] == "tuning":
            continue
        label = r["labels"][0] if r["labels"] else None
        onset = onset_of(label)
        alarms = [a.time_s for a in decide(det, f)[0].alarms]
        d = dx.from_features(f, onset) if label else None
        rows.append(_outcome(t, label, onset, det.reference_s, f, alarms, d))
    return det, rows


def _outcome(task: dict[str, Any], label: dict[str, Any] | None, onset: float | None,
             start: float, f: BlockFeatures, alarms: list[float], dx: Any) -> dict[str, Any]:  # fmt: skip
    top = None
    if dx is not None and dx.alarm is not None and dx.causes:
        top = (dx.alarm.time_s, [{"element": c.element, "kind": c.kind, "family": c.family,
                                  "severity": c.severity, "group": list(c.group)}
                                 for c in dx.causes[:3]])  # fmt: skip
    return outcome(task, label, onset, start, float(f.time_s[-1]), alarms, top)


def outcome(task: dict[str, Any], label: dict[str, Any] | None, onset: float | None,
            start: float, end: float, alarms: list[float],
            top: tuple[float, list[dict[str, Any]]] | None) -> dict[str, Any]:  # fmt: skip
    """One record's row of the benchmark table (record times, s): its fault-free running
    after ``start`` and the alarms in it; for a fault, detection and delay (the first alarm at
    or after the onset), and the causes named for that alarm (``top``: the alarm's time and
    its first causes as dicts with element, kind, family, severity and group; the live
    twin's events give the same)."""
    free_until = end if onset is None else onset
    false = [a for a in alarms if a < free_until]
    out: dict[str, Any] = {"name": task["name"], "set": task["set"],
                           "healthy_s": max(0.0, free_until - start), "false_alarms": len(false)}  # fmt: skip
    if label is None or onset is None:
        return out
    hits = [a for a in alarms if a >= onset]
    out.update({"kind": label["kind"], "element": label["element"], "family": label["family"],
                "level": task["level"], "profile": task["profile"], "severity": label["severity"],
                "detected": bool(hits), "delay_s": (hits[0] - onset) if hits else None})  # fmt: skip
    if top is not None and top[0] >= onset and top[1]:
        names = [f"{c['element']}:{c['kind']}" for c in top[1]]
        truth = f"{label['element']}:{label['kind']}"
        first = top[1][0]
        out.update({"top": names[:3], "top1": names[0] == truth, "top3": truth in names[:3],
                    "group_hit": truth in (names[0], *first.get("group", [])),
                    "top_family": first["family"], "severity_est": first["severity"]})  # fmt: skip
    return out


def _pct(xs: Sequence[bool]) -> float | None:
    return None if not xs else 100.0 * float(np.mean(xs))


def score(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The benchmark table of one method."""
    faults = [r for r in rows if "kind" in r]
    assessable = [r for r in faults if r["kind"] not in NOT_ASSESSED]
    hidden = [r for r in faults if r["kind"] in NOT_ASSESSED]
    hours = sum(r["healthy_s"] for r in rows) / 3600.0
    n_false = sum(r["false_alarms"] for r in rows)
    out: dict[str, Any] = {
        "records": len(faults),
        "detection_pct": {LEVEL_NAMES[lv]: _pct([r["detected"] for r in assessable if r["level"] == lv])
                          for lv in range(3)},
        "detection_pct_moderate_severe": _pct([r["detected"] for r in assessable if r["level"] >= 1]),
        "detection_pct_not_assessed": _pct([r["detected"] for r in hidden]),
        "false_alarms": n_false, "healthy_hours": hours,
        "false_alarms_per_24h": n_false / hours * 24 if hours > 0 else None,
        "false_alarms_per_24h_upper95": poisson_upper(n_false, hours),
    }  # fmt: skip
    for prof in ("step", "ramp"):
        d = [r["delay_s"] for r in assessable if r["profile"] == prof and r["detected"]]
        out[f"delay_{prof}_s"] = {"median": float(np.median(d)) if d else None,
                                  "p90": float(np.percentile(d, 90)) if d else None,
                                  "detected": len(d),
                                  "of": sum(r["profile"] == prof for r in assessable)}  # fmt: skip
    located = [r for r in assessable if "top1" in r]
    ms = [r for r in located if r["level"] >= 1]
    out["localisation"] = None if not located else {
        "located": len(located),
        "top1_pct": _pct([r["top1"] for r in ms]), "top3_pct": _pct([r["top3"] for r in ms]),
        "group_hit_pct": _pct([r["group_hit"] for r in ms]),
        # stuck and dropout are named by rules that measure them in other units
        "severity_rel_error_median": _median_rel([r for r in located if r["top1"]
                                                  and r["kind"] not in ("stuck", "dropout")]),
        "sensor_blamed_on_machine": sum(r["family"] == "sensor" and r["top_family"] != "sensor"
                                        for r in located),
        "machine_blamed_on_sensor": sum(r["family"] != "sensor" and r["top_family"] == "sensor"
                                        for r in located),
    }  # fmt: skip
    out["confusion"] = _confusion(faults)
    out["by_kind"] = by_kind(faults)
    return out


def by_kind(rows: Sequence[dict[str, Any]]) -> dict[str, dict[str, dict[str, Any]]]:
    """Per fault kind and severity (both profiles): records, detected, the abrupt and the
    ramp record's delay, placed first (top-1) and inside the first cause's look-alike group,
    counted over all its records (a missed fault is not placed)."""
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for r in rows:
        if "kind" not in r:
            continue
        cell = out.setdefault(r["kind"], {}).setdefault(
            LEVEL_NAMES[r["level"]],
            {"records": 0, "detected": 0, "top1": 0, "group_hit": 0, "delay_s": {}},
        )
        cell["records"] += 1
        cell["detected"] += bool(r["detected"])
        cell["top1"] += bool(r.get("top1"))
        cell["group_hit"] += bool(r.get("group_hit"))
        cell["delay_s"][r["profile"]] = r["delay_s"]
    return out


def _median_rel(rows: Sequence[dict[str, Any]]) -> float | None:
    errs = [abs(r["severity_est"] - r["severity"]) / abs(r["severity"]) for r in rows]
    return float(np.median(errs)) if errs else None


def _confusion(faults: Sequence[dict[str, Any]]) -> dict[str, dict[str, int]]:
    """True kind -> predicted kind of the first cause ('missed' when not detected, 'not
    located' when detected without a ranking)."""
    out: dict[str, dict[str, int]] = {k: {} for k in KINDS if any(r["kind"] == k for r in faults)}
    for r in faults:
        if not r["detected"]:
            pred = "missed"
        elif "top" in r:
            pred = r["top"][0].split(":")[1]
        else:
            pred = "not located"
        out[r["kind"]][pred] = out[r["kind"]].get(pred, 0) + 1
    return out
