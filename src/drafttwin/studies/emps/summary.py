"""The EMPS benchmark's table: one row per (task, model) over the seeds."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from drafttwin.studies.emps.plan import PUBLISHED, EmpsConfig, score_start


def summarise(results: Sequence[dict[str, Any]], config: EmpsConfig) -> list[dict[str, Any]]:
    """One row per (task, model, physics variant): RMSE over seeds (mean, std, min, max) and
    the rest; ``physics`` is the variant (``None`` for models without physics)."""
    rows = []
    for task, name, kind in ((t, m, k) for t in config.tasks for m in config.models
                             for k in (*config.physics_variants, None)):  # fmt: skip
        runs = [r for r in results if r["task"] == task and r["model"] == name
                and r.get("physics") == kind]  # fmt: skip
        if not runs:
            continue
        rmse = np.array([r["rmse_mm"] for r in runs])
        row: dict[str, Any] = {
            "task": task, "model": name, "physics": kind, "runs": len(runs),
            "rmse_mm": rmse.tolist(), "rmse_mm_mean": float(rmse.mean()),
            "rmse_mm_std": float(rmse.std(ddof=1)) if len(runs) > 1 else 0.0,
            "rmse_mm_min": float(rmse.min()), "rmse_mm_max": float(rmse.max()),
            "fit_pct_mean": float(np.mean([r["fit_pct"] for r in runs])),
            "fit_s_mean": float(np.mean([r["fit_s"] for r in runs])),
            "predict_s_mean": float(np.mean([r["predict_s"] for r in runs])),
            "n_nan": int(max(r["n_nan"] for r in runs)),
            "score_from_row": score_start(task),
        }  # fmt: skip
        if all("train_rmse_mm" in r for r in runs):
            row["train_rmse_mm_mean"] = float(np.mean([r["train_rmse_mm"] for r in runs]))
        if task == "simulation" and name in PUBLISHED and kind != "refitted":
            row["published_rmse_mm"] = PUBLISHED[name]["rmse_mm"]
        rows.append(row)
    return rows
