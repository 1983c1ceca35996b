"""The report's tables as tidy DataFrames (written as CSV and rendered into the HTML).

Every function takes the study's ``results`` dictionary (schema in
``drafttwin.studies.paper.run``) and returns a DataFrame; the paper's published values
(``drafttwin.report.paper``) sit beside ours where the paper has them.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np
import pandas as pd

from drafttwin._constants import ROLLERS
from drafttwin.report import paper

METRIC_COLUMNS = (
    "rmse",
    "nrmse",
    "skill",
    "mean_rel_err_pct",
    "max_rel_err_pct",
    "accuracy_pct",
    "rmse_floor",
    "rmse_vs_true",
    "sensor_rmse",
    "true_error_ratio",
    "rmse_persistence",
    "rel_threshold",
    "n_scored",
    "n_rel_excluded",
    "n_nan_pred",
)
"""Numeric columns of the metrics table; RMSEs, floor, sensor error and threshold in
``unit``."""
COUNT_COLUMNS = ("n_scored", "n_rel_excluded", "n_nan_pred")


def as_float(value: Any) -> float:
    """A float, NaN for ``None`` (JSON null)."""
    return float("nan") if value is None else float(value)


def metric_unit(results: Mapping[str, Any]) -> str:
    """The unit of the comparison's metrics: the ``unit`` its rows share, ``""`` if they do
    not share one or do not declare it."""
    units = {
        str(m.get("unit") or "")
        for per_model in results["comparison"]["metrics"].values()
        for m in per_model.values()
    }
    return units.pop() if len(units) == 1 else ""


def compared_models(results: Mapping[str, Any]) -> tuple[list[str], list[str]]:
    """(main models, extra variants) of the comparison, in the study's order."""
    comp = results["comparison"]
    return list(comp["models"]), list(comp.get("extra", []))


def comparison_metrics(
    results: Mapping[str, Any],
) -> Iterator[tuple[str, str, bool, Mapping[str, Any]]]:
    """(model, roller, is an extra variant, its metrics) over the comparison, models in the
    study's order (extra variants last), rollers front to back."""
    main, extra = compared_models(results)
    metrics = results["comparison"]["metrics"]
    for model in main + extra:
        for roller in ROLLERS:
            yield model, roller, model in extra, metrics[model][roller]


def paper_table2(model: str, roller: str) -> tuple[float, float]:
    """The paper's (max, mean) relative error in % for a model and roller; NaN if absent."""
    row = paper.TABLE2.get(model)
    if row is None:
        return float("nan"), float("nan")
    j = paper.ROLLER_ORDER.index(roller)
    return row["max"][j], row["mean"][j]


def table2(results: Mapping[str, Any]) -> pd.DataFrame:
    """Table 2 analogue: max / mean relative error per model and roller, ours and the paper's."""
    rows = []
    for model, roller, extra, m in comparison_metrics(results):
        p_max, p_mean = paper_table2(model, roller)
        rows.append(
            {
                "model": model,
                "roller": roller,
                "extra": extra,
                "max_rel_err_pct": as_float(m["max_rel_err_pct"]),
                "mean_rel_err_pct": as_float(m["mean_rel_err_pct"]),
                "paper_max_rel_err_pct": p_max,
                "paper_mean_rel_err_pct": p_mean,
            }
        )
    return pd.DataFrame(rows)


def metrics_table(results: Mapping[str, Any]) -> pd.DataFrame:
    """All honest and paper metrics, one row per model and roller."""
    rows = []
    for model, roller, extra, m in comparison_metrics(results):
        row: dict[str, Any] = {"model": model, "roller": roller, "extra": extra,
                               "unit": m.get("unit", "")}  # fmt: skip
        row.update({c: as_float(m.get(c)) for c in METRIC_COLUMNS})
        row["rel_note"] = m.get("rel_note") or ""
        rows.append(row)
    frame = pd.DataFrame(rows)
    for c in COUNT_COLUMNS:
        frame[c] = frame[c].astype("Int64")
    return frame


def table3(results: Mapping[str, Any]) -> pd.DataFrame:
    """Table 3 analogue: accuracy per variant, repeated test and roller, with the paper's."""
    abl = results["ablation"]
    seeds = list(abl["seeds"])
    unit = metric_unit(results)
    rows = []
    for variant in abl["variants"]:
        acc = np.asarray(abl["accuracy"][variant], dtype=float)
        rmse = np.asarray(abl.get("rmse", {}).get(variant, np.full_like(acc, np.nan)), dtype=float)
        k = paper.TABLE3_VARIANTS.index(variant) if variant in paper.TABLE3_VARIANTS else None
        for i, seed in enumerate(seeds):
            for j, roller in enumerate(ROLLERS):
                published = paper.TABLE3[roller]
                p = published[i][k] if k is not None and i < len(published) else float("nan")
                rows.append(
                    {
                        "variant": variant,
                        "test": i + 1,
                        "seed": seed,
                        "roller": roller,
                        "accuracy_pct": acc[i, j],
                        "rmse": rmse[i, j],
                        "unit": unit,
                        "paper_accuracy_pct": p,
                    }
                )
    return pd.DataFrame(rows)


def paper_table3_stats(roller: str, variant: str) -> tuple[float, float]:
    """Mean and sample std of the paper's ten Table 3 accuracies; NaN if not in the paper."""
    if variant not in paper.TABLE3_VARIANTS:
        return float("nan"), float("nan")
    k = paper.TABLE3_VARIANTS.index(variant)
    vals = np.array([row[k] for row in paper.TABLE3[roller]])
    return float(vals.mean()), float(vals.std(ddof=1))


def table3_summary(results: Mapping[str, Any]) -> pd.DataFrame:
    """Per variant and roller: our mean/std/min/max accuracy over the tests and the paper's."""
    abl = results["ablation"]
    rows = []
    for variant in abl["variants"]:
        for roller in ROLLERS:
            s = abl["summary"][variant][roller]
            p_mean, p_std = paper_table3_stats(roller, variant)
            rows.append(
                {
                    "variant": variant,
                    "roller": roller,
                    **{k: as_float(s[k]) for k in ("mean", "std", "min", "max")},
                    "paper_mean": p_mean,
                    "paper_std": p_std,
                }
            )
    return pd.DataFrame(rows)


def grid_table(results: Mapping[str, Any]) -> pd.DataFrame:
    """Every grid-search configuration, with a flag on each network's best one."""
    grid = results["grid"]
    rows = []
    for net in ("lstm", "gru"):
        best = grid.get("best", {}).get(net, {})
        for r in grid.get(net, []):
            is_best = all(r.get(k) == best.get(k) for k in ("lr", "hidden", "layers")) and bool(
                best
            )
            rows.append(
                {
                    "network": net,
                    "lr": r["lr"],
                    "hidden": r["hidden"],
                    "layers": r["layers"],
                    "val_loss": as_float(r["val_loss"]),
                    "epochs": r.get("epochs"),
                    "wall_s": as_float(r.get("wall_s")),
                    "best": is_best,
                }
            )
    return pd.DataFrame(
        rows, columns=["network", "lr", "hidden", "layers", "val_loss", "epochs", "wall_s", "best"]
    )
