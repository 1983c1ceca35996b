"""Summaries of the benchmark's rows: the extrapolation table, the learning curves, each
hybrid's RMSE relative to the GRU with its spread over seeds, and the issue's checks."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable
from typing import Any

import numpy as np

HYBRIDS = ("parallel", "md-s-l")
HARD = ("draft-gears", "speed+25", "speed-25")
"""Where the physics should pay most: free runs on changed gears and at +-25 % speed."""

Row = dict[str, Any]


def _stats(values: Iterable[float | None]) -> dict[str, Any]:
    x = np.array([v for v in values if v is not None and np.isfinite(v)], dtype=np.float64)
    if x.size == 0:
        return {"mean": None, "std": None, "min": None, "max": None, "n": 0}
    # the float mean of equal values can sit an ulp outside them (3 x 0.7: -1.1e-16), and the
    # report's error bars (mean - min, max - mean) must not be negative
    mean = float(np.clip(x.mean(), x.min(), x.max()))
    spread = x.size > 1 and x.max() > x.min()  # equal values: 0, not 6.8e-17
    return {"mean": mean, "std": float(x.std(ddof=1)) if spread else 0.0,
            "min": float(x.min()), "max": float(x.max()), "n": int(x.size)}  # fmt: skip


def _label(row: Row) -> str:
    """The model as the tables show it (the calibrated physics apart)."""
    return "mechanistic (calibrated)" if row.get("physics") == "calibrated" else row["model"]


def extrapolation(rows: list[Row], train_s: float) -> list[Row]:
    """Per scenario, task, model and channel: RMSE and skill over seeds at the full training
    length (the little-data scenario too: the same models on the training set-point)."""
    groups: dict[tuple[str, str, str, str], list[Row]] = defaultdict(list)
    for r in rows:
        if r["train_s"] == train_s:
            groups[(r["scenario"], r["task"], _label(r), r["channel"])].append(r)
    return [{"scenario": s, "task": t, "model": m, "channel": c,
             "rmse": _stats(r["rmse"] for r in g), "skill": _stats(r["skill"] for r in g)}
            for (s, t, m, c), g in groups.items()]  # fmt: skip


def learning_curves(rows: list[Row]) -> list[Row]:
    """Per task, model, training length and channel on the little-data test record."""
    groups: dict[tuple[str, str, float, str], list[Row]] = defaultdict(list)
    for r in rows:
        if r["scenario"] == "little-data":
            groups[(r["task"], _label(r), r["train_s"], r["channel"])].append(r)
    return [{"task": t, "model": m, "train_s": n, "channel": c,
             "rmse": _stats(r["rmse"] for r in g)}
            for (t, m, n, c), g in sorted(groups.items(), key=lambda kv: kv[0][:3])]  # fmt: skip


def hybrid_ratios(rows: list[Row]) -> list[Row]:
    """Each hybrid's RMSE over the GRU's of the same seed, per scenario, task, training
    length and channel, with the spread over seeds (below 1: the hybrid is better)."""
    gru = {(r["scenario"], r["task"], r["train_s"], r["seed"], r["channel"]): r["rmse"]
           for r in rows if r["model"] == "gru"}  # fmt: skip
    groups: dict[tuple[str, str, str, float, str], list[float]] = defaultdict(list)
    for r in rows:
        if r["model"] not in HYBRIDS:
            continue
        base = gru.get((r["scenario"], r["task"], r["train_s"], r["seed"], r["channel"]))
        if base is not None and base > 0 and r["rmse"] is not None:
            groups[(r["scenario"], r["task"], r["model"], r["train_s"], r["channel"])].append(
                r["rmse"] / base
            )
    return [{"scenario": s, "task": t, "model": m, "train_s": n, "channel": c,
             "ratio_to_gru": _stats(v)} for (s, t, m, n, c), v in groups.items()]  # fmt: skip


def checks(table: list[Row]) -> list[Row]:
    """The issue's test: in free runs on the changed gears and at +-25 % speed, do the physics
    and at least one hybrid beat the GRU (mean over seeds) on every roller?"""
    mean = {(r["scenario"], r["task"], r["model"], r["channel"]): r["rmse"]["mean"]
            for r in table}  # fmt: skip
    out = []
    for scenario in HARD:
        channels = sorted({r["channel"] for r in table if r["scenario"] == scenario})
        if not channels:
            continue
        per: dict[str, dict[str, bool | None]] = {}
        for c in channels:
            g = mean.get((scenario, "simulation", "gru", c))
            phys = mean.get((scenario, "simulation", "mechanistic", c))
            hyb = [mean.get((scenario, "simulation", h, c)) for h in HYBRIDS]
            hyb_ok = [h < g for h in hyb if h is not None and g is not None]
            per[c] = {"physics_beats_gru": None if g is None or phys is None else phys < g,
                      "a_hybrid_beats_gru": any(hyb_ok) if hyb_ok else None}  # fmt: skip
        ok = all(v["physics_beats_gru"] and v["a_hybrid_beats_gru"] for v in per.values())
        out.append({"scenario": scenario, "task": "simulation", "holds": bool(ok),
                    "channels": per})  # fmt: skip
    return out


def summarise(rows: list[Row], train_s: float) -> dict[str, Any]:
    """The summaries added to the benchmark's JSON document."""
    table = extrapolation(rows, train_s)
    return {"extrapolation": table, "learning_curves": learning_curves(rows),
            "hybrid_vs_gru": hybrid_ratios(rows), "checks": checks(table)}  # fmt: skip
