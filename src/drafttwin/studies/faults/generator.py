"""Is the reduced plant a cheaper generator of the benchmark's healthy running?

The full plant costs about 5.6 CPU-s per minute of healthy running (99 % in the full drive
train's RK4 kernel), so 24 h of it cost about 8 300 CPU-s. The plant with the machine's train
reduced (:class:`~drafttwin.plant.Plant` ``reduced_hz``: every coupling but the belt rigid) is
about 80 times cheaper. It may stand in for the full plant's healthy records only if the
detector sees the same statistics in both. :func:`compare` records the same machines with the
same recording seeds on both plants and sets side by side what the detector uses:

* per block-feature channel (four roller levels, the motor level, three angle lags): mean,
  standard deviation and lag-1 autocorrelation of its deviation from the record's reference
  window, and its longest run of identical readings (what the stuck rule watches);
* per detector stream: what :meth:`~drafttwin.diagnosis.detect.FaultDetector.fit` takes from
  each plant's records (scale, AR(1) coefficient, long-run variance factor, the lags' jump
  limit);
* the decisions of one detector, fitted on separate full-plant tuning records as the
  benchmark fits it: per record, the largest CUSUM over its threshold, the largest lag jump
  over its limit, the largest sensor statistic over its limit, and the alarms.

docs/faults.md gives the table and the verdict (measured: six machines x 120 s, seed 1): the
roller and motor levels agree within 1 %, but the reduced plant's belt stream is 1.4 and its
parity streams 1.8-3 times narrower, its third-roller lag 5.5 times narrower, and the encoders
of its second, third and back rollers repeat one count up to 87 samples (the full plant's at
most 10), which the stuck rule flags: 183 sensor alarms in 0.2 h against one belt alarm. It is not used for the benchmark's healthy running.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from drafttwin.diagnosis.cusum import FEATURES, STREAMS, feature_matrix
from drafttwin.diagnosis.detect import FaultDetector
from drafttwin.diagnosis.residuals import BlockFeatures
from drafttwin.studies.faults.plan import run_record
from drafttwin.studies.faults.score import features

GENERATORS = ("full", "reduced")


def tasks(n_tuning: int, n_healthy: int, duration_s: float, seed: int) -> list[dict[str, Any]]:
    """Full-plant tuning records, then each healthy machine and seed on both plants."""
    rng = np.random.default_rng(seed)
    out: list[dict[str, Any]] = []
    for i in range(n_tuning + n_healthy):
        m, s = (int(x) for x in rng.integers(0, 2**31, size=2))
        base = {"machine_seed": m, "seed": s, "duration_s": duration_s, "faults": []}
        if i < n_tuning:
            out.append({**base, "set": "tuning", "name": f"tuning_{i}"})
            continue
        for g in GENERATORS:
            task = {**base, "set": g, "name": f"healthy_{i - n_tuning}"}
            if g != "full":
                task["generator"] = g
            out.append(task)
    return out


def channel_stats(fs: Sequence[BlockFeatures], reference_s: float) -> dict[str, dict[str, float]]:
    """Per feature channel, pooled over the records: deviation from each record's
    reference window (mean, SD, lag-1 autocorrelation), the mean level itself, and the
    longest run of identical readings (levels only)."""
    devs, pairs, levels = [], [], []
    for f in fs:
        x = feature_matrix(f)
        n_ref = max(2, int(round(reference_s / f.block_s)))
        d = x[n_ref:] - np.nanmean(x[:n_ref], axis=0)
        devs.append(d)
        pairs.append((d[:-1], d[1:]))
        levels.append(x)
    d_all, lv = np.vstack(devs), np.vstack(levels)
    x0, x1 = np.vstack([p[0] for p in pairs]), np.vstack([p[1] for p in pairs])
    runs = np.vstack([f.run for f in fs])
    out: dict[str, dict[str, float]] = {}
    for j, name in enumerate(FEATURES):
        ok = np.isfinite(x0[:, j]) & np.isfinite(x1[:, j])
        a, b = x0[ok, j] - x0[ok, j].mean(), x1[ok, j] - x1[ok, j].mean()
        out[name] = {"level_mean": float(np.nanmean(lv[:, j])),
                     "dev_mean": float(np.nanmean(d_all[:, j])),
                     "dev_sd": float(np.nanstd(d_all[:, j])),
                     "ac1": float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))}  # fmt: skip
        if j < runs.shape[1]:
            out[name]["run_max"] = float(runs[:, j].max())
            out[name]["run_median"] = float(np.median(runs[:, j]))
    return out


def _detector_stats(det: FaultDetector) -> dict[str, dict[str, float]]:
    return {s: {"sigma": float(det.sigma_[i]), "phi": float(det.phi_[i]),
                "long_run": float(det.long_run_[i]), "jump_limit": float(det.jump_limit_[i])}
            for i, s in enumerate(STREAMS)}  # fmt: skip


def _decisions(det: FaultDetector, f: BlockFeatures) -> dict[str, Any]:
    d = det.run(f, stop_at_first=False)
    watched = det.watched_
    return {"cusum_max": float(np.nanmax(d.statistic[:, watched])),
            "cusum_stream": STREAMS[int(np.nanargmax(np.nanmax(d.statistic, axis=0)))],
            "jump_max": float(np.nanmax(d.jump)) if d.jump is not None else 0.0,
            "sensor_max": float(np.nanmax(d.sensor)) if d.sensor is not None else 0.0,
            "alarms": [(a.time_s, a.test, a.rule) for a in d.alarms]}  # fmt: skip


def compare(
    n_tuning: int = 4, n_healthy: int = 6, duration_s: float = 120.0, seed: int = 1
) -> dict[str, Any]:
    """The comparison (JSON-able): per plant, channel and detector statistics and the
    decisions of the detector fitted on the full-plant tuning records; CPU-s per plant."""
    import time

    todo = tasks(n_tuning, n_healthy, duration_s, seed)
    cpu: dict[str, float] = dict.fromkeys(GENERATORS, 0.0)
    results = []
    for t in todo:  # in this process: each record's CPU time is its plant's
        c0 = time.process_time()
        results.append(features(run_record(t)))
        cpu["full" if t["set"] == "tuning" else t["set"]] += time.process_time() - c0
    tuning = FaultDetector().fit([f for t, f in zip(todo, results, strict=True)
                                  if t["set"] == "tuning"])  # fmt: skip
    out: dict[str, Any] = {"n_tuning": n_tuning, "n_healthy": n_healthy,
                           "duration_s": duration_s, "seed": seed, "cpu_s": cpu,
                           "h": tuning.h_, "generators": {}}  # fmt: skip
    for g in GENERATORS:
        fs = [f for t, f in zip(todo, results, strict=True) if t["set"] == g]
        out["generators"][g] = {
            "channels": channel_stats(fs, tuning.reference_s),
            "detector": _detector_stats(FaultDetector().fit(fs)),
            "decisions": [_decisions(tuning, f) for f in fs],
        }
    return out


__all__ = ["GENERATORS", "channel_stats", "compare", "tasks"]
