"""The report's calibration section: nominal against calibrated physics, alone and under the
hybrids, and what the calibration estimated. Does better physics make the hybrid better?"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from drafttwin._constants import ROLLERS
from drafttwin.report.agreement import label
from drafttwin.report.fmt import DASH, is_num, num, sig
from drafttwin.report.html import Cell, Raw, join, para, section, table

PHYSICS = ("nominal", "calibrated")


def _metric_table(cal: Mapping[str, Any], key: str, nd: int) -> Raw:
    """One row per model and physics, one column per roller; the better physics in green."""
    body = []
    for model in cal["models"]:
        values = {p: cal["metrics"][p][model] for p in PHYSICS}
        for phys in PHYSICS:
            cells: list[Any] = [Cell(label(model), header=True), phys]
            for r in ROLLERS:
                mine, other = values[phys][r].get(key), values[_other(phys)][r].get(key)
                better = is_num(mine) and is_num(other) and _better(key, mine, other)
                cells.append(Cell(num(mine, nd), cls="best" if better else None))
            body.append(cells)
    return table([["model", "physics", *ROLLERS]], body, cls="num")


def _other(phys: str) -> str:
    return PHYSICS[1 - PHYSICS.index(phys)]


def _better(key: str, mine: float, other: float) -> bool:
    return mine > other if key == "skill" else abs(mine) < abs(other)


def _parameter_table(report: Mapping[str, Any]) -> Raw:
    """Every parameter the data saw: a group of parameters that act together once."""
    body, seen = [], set()
    for p in report["parameters"]:
        if p["verdict"] == "not from this data":
            continue
        group = tuple(sorted([p["name"], *p.get("combined_with", [])]))
        if group in seen:
            continue
        seen.add(group)
        name = p["name"] + (f" (+{len(group) - 1} acting with it)" if len(group) > 1 else "")
        se = p.get("factor_std_error")
        body.append([name, num(p["factor"], 4), num(se, 4) if is_num(se) else DASH, p["verdict"]])
    unseen = sum(p["verdict"] == "not from this data" for p in report["parameters"])
    caption = f"{unseen} more not seen by these data (left nominal)" if unseen else None
    return table([["parameter", "factor of nominal", "± SE", "verdict"]], body, cls="num",
                 caption=caption)  # fmt: skip


def calibration_section(results: Mapping[str, Any]) -> Raw:
    """Section: the calibration stage (empty for results written before it existed)."""
    cal = results.get("calibration")
    if not cal or not cal.get("report"):
        return Raw("")
    rep = cal["report"]
    return section(
        "calibration",
        "Calibrated physics",
        para(
            f"The drive train, {cal.get('note', 'calibrated on the training part only')}. "
            f"Block-mean RMSE on the training part {sig(rep['rmse_before'])} → "
            f"{sig(rep['rmse_after'])} rpm, {rep['simulations']} simulations in "
            f"{num(rep['wall_s'], 1)} s. Then the physics alone and the hybrids on top of each, "
            "scored on the test part (green: the better of the two physics)."
        ),
        _parameter_table(rep),
        join([Raw("<h3>RMSE (rpm)</h3>"), _metric_table(cal, "rmse", 3)]),
        join([Raw("<h3>Bias: mean error (rpm)</h3>"), _metric_table(cal, "bias", 3)]),
        join([Raw("<h3>Skill against persistence</h3>"), _metric_table(cal, "skill", 3)]),
    )
