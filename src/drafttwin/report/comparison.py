"""Sections 2 and 3 of the report: the model comparison (Table 2 analogue, honest metrics)
and the prediction / residual figures (Fig. 8 analogue)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from drafttwin._constants import ROLLERS
from drafttwin.data.preprocessing import DEFAULT_TRAIN_FRACTION
from drafttwin.report.agreement import label
from drafttwin.report.fmt import DASH, is_num, num, with_unit
from drafttwin.report.html import Cell, figure, join, para, section, table, tag
from drafttwin.report.overview import is_plant
from drafttwin.report.tables import compared_models, metric_unit, paper_table2

if TYPE_CHECKING:
    from drafttwin.report.html import BodyRow, CellLike, Raw, Row

# (key, header, decimals, lower is better); headers in UNIT_HEADERS get the metrics' unit
HONEST = (
    ("rmse", "RMSE", 3, True),
    ("rmse_vs_true", "RMSE vs true", 3, True),
    ("true_error_ratio", "vs true / sensor error", 3, True),
    ("nrmse", "NRMSE", 3, True),
    ("skill", "skill vs persistence", 3, False),
    ("mean_rel_err_pct", "mean rel. err. (%)", 4, True),
    ("max_rel_err_pct", "max rel. err. (%)", 4, True),
    ("accuracy_pct", "accuracy (%)", 4, False),
)
UNIT_HEADERS = ("rmse", "rmse_vs_true")
LIMITS_TEXT = (
    "Where the true speed is known, two limits say what the errors mean. The floor is the "
    "lowest RMSE any one-step predictor of the measured speed can reach: an oracle that knows "
    "the true speed and every earlier measurement. It lies below the encoders' own error "
    "because consecutive sample windows share a boundary, whose counting error enters them "
    "with opposite signs: part of the next error can be foreseen. No model can score below it. "
    "RMSE vs true compares the prediction with the plant's true speed, not the measured one; "
    "divided by the encoder error (measured vs true), below 1 means the model estimates the "
    "true speed better than the encoder measures it."
)


def _value(results: Mapping[str, Any], model: str, roller: str, key: str) -> float:
    v = results["comparison"]["metrics"][model][roller].get(key)
    return float(v) if is_num(v) else float("nan")


def _best(results: Mapping[str, Any], models: list[str], roller: str, key: str, lower: bool) -> str:
    """The model with the best finite value (ties: the first); '' if none."""
    vals = {m: _value(results, m, roller, key) for m in models}
    finite = {m: v for m, v in vals.items() if np.isfinite(v)}
    if not finite:
        return ""
    pick: Callable[..., str] = min if lower else max
    return pick(finite, key=finite.__getitem__)


def _table2_rows(results: Mapping[str, Any], main: list[str], extra: list[str]) -> list[BodyRow]:
    best = {
        (k, r): _best(results, main, r, f"{k}_rel_err_pct", True)
        for k in ("max", "mean")
        for r in ROLLERS
    }
    body: list[BodyRow] = []
    for model in main + extra:
        cells: list[CellLike] = [Cell(label(model), cls="name"), Cell("ours", cls="name")]
        for k in ("max", "mean"):
            for r in ROLLERS:
                v = _value(results, model, r, f"{k}_rel_err_pct")
                cls = "best" if model in main and best[(k, r)] == model else None
                cells.append(Cell(num(v, 4), cls=cls))
        if extra and model == extra[0]:
            body.append(
                (
                    "group",
                    [Cell("Extra variants (reported separately; not in the paper)", colspan=10)],
                )
            )
        body.append(("extra" if model in extra else "ours", cells))
        if model in main:
            body.append(("paper", _paper_table2_cells(model)))
    return body


def _paper_table2_cells(model: str) -> list[CellLike]:
    cells: list[CellLike] = [Cell("", cls="name"), Cell("paper (real FA320A)", cls="name")]
    if not np.isfinite(paper_table2(model, ROLLERS[0])[0]):
        return cells + [Cell("not in the paper", colspan=8, cls="name")]
    for k in (0, 1):
        cells += [num(paper_table2(model, r)[k], 3) for r in ROLLERS]
    return cells


def table2_html(results: Mapping[str, Any]) -> Raw:
    """Table 2 analogue with the paper's published values interleaved."""
    main, extra = compared_models(results)
    head: list[Row] = [
        [
            Cell("model", header=True, rowspan=2, cls="name"),
            Cell("source", header=True, rowspan=2, cls="name"),
            Cell("max relative error (%)", header=True, colspan=4),
            Cell("mean relative error (%)", header=True, colspan=4),
        ],
        [*ROLLERS, *ROLLERS],
    ]
    return table(head, _table2_rows(results, main, extra), id="table2")


def _honest_rows(results: Mapping[str, Any], main: list[str], extra: list[str]) -> list[BodyRow]:
    body: list[BodyRow] = []
    ncol = len(HONEST) + 3
    for r in ROLLERS:
        body.append(("group", [Cell(f"{r} roller", colspan=ncol)]))
        body += _limit_rows(results, main[0], r, ncol)
        best = {key: _best(results, main, r, key, lower) for key, _, _, lower in HONEST}
        for model in main + extra:
            name = label(model) + (" (extra)" if model in extra else "")
            cells: list[CellLike] = [Cell(name, cls="name")]
            for key, _, nd, _ in HONEST:
                cls = "best" if model in main and best[key] == model else None
                cells.append(Cell(num(_value(results, model, r, key), nd), cls=cls))
            n = results["comparison"]["metrics"][model][r]
            cells += [str(n.get("n_scored", DASH)), str(n.get("n_nan_pred", DASH))]
            body.append(("extra" if model in extra else "", cells))
    return body


def _limit_rows(
    results: Mapping[str, Any], model: str, roller: str, ncol: int
) -> list[tuple[str, list[CellLike]]]:
    """The accuracy limits of a roller (scored on ``model``'s rows), under the columns they
    bound: the floor under RMSE, the encoders' own error under RMSE vs true."""
    floor = _value(results, model, roller, "rmse_floor")
    sensor = _value(results, model, roller, "sensor_rmse")
    if not (is_num(floor) or is_num(sensor)):
        return []
    return [
        ("floor", [Cell("floor: lowest RMSE any predictor can reach", cls="name"), num(floor, 3),
                   *[""] * (ncol - 2)]),
        ("floor", [Cell("encoder error (measured vs true)", cls="name"), "", num(sensor, 3),
                   *[""] * (ncol - 3)]),
    ]  # fmt: skip


def _rel_notes(results: Mapping[str, Any]) -> list[str]:
    """``"front (signal crosses zero: ...)"`` for every roller whose relative errors the
    metrics omit, with the reason (the first model's; it depends on the measurement)."""
    main = compared_models(results)[0]
    out = []
    for r in ROLLERS:
        note = results["comparison"]["metrics"][main[0]][r].get("rel_note")
        if note:
            out.append(f"{r} ({note})")
    return out


def metrics_html(results: Mapping[str, Any]) -> Raw:
    """The honest metrics per roller and model; best value per roller highlighted."""
    main, extra = compared_models(results)
    unit = metric_unit(results)
    head: list[Row] = [
        [
            Cell("model", header=True, cls="name"),
            *[with_unit(h, unit) if k in UNIT_HEADERS else h for k, h, _, _ in HONEST],
            "n scored",
            "no prediction",
        ]
    ]
    return table(head, _honest_rows(results, main, extra), id="metrics")


def comparison_section(results: Mapping[str, Any], figs: Mapping[str, bytes]) -> Raw:
    """Section 2: RMSE figure, Table 2 analogue, honest metrics."""
    extra = compared_models(results)[1]
    data = results["data"]
    source = "plant-emulator data" if is_plant(results) else f"data set {data.get('name')}"
    share = 1 - float(data.get("train_fraction") or DEFAULT_TRAIN_FRACTION)
    parts: list[Raw | str] = [
        tag("h3", "Table 2 analogue: relative errors"),
        para(
            f"Ours: the test part of the {source} (last {share:.0%} of the record), "
            "one-step-ahead predictions. Paper: Table 2 as published, measured on a real FA320A. "
            "The paper has no persistence row. Best of our models per column in green."
        ),
        table2_html(results),
        tag("h3", "Honest metrics"),
        para(
            "Relative errors look tiny because the speeds are large and nearly constant: skill "
            "says whether a model beats simply repeating the last measurement. "
            + (LIMITS_TEXT if is_plant(results) else "")
        ),
        metrics_html(results),
    ]
    if "rmse" in figs:
        parts.insert(
            0,
            figure(
                figs["rmse"],
                "fig-rmse",
                "RMSE per model and roller against the measured speed (filled dots) and "
                "the plant's true speed (open dots); dashed line: the floor of one-step "
                "prediction of the measured speed; dotted line: the encoders' own error "
                "(measured vs true). Log scale."
                if is_plant(results)
                else "RMSE per model and roller against the measured speed (no true speed "
                "is known for these measurements); dashed line: the floor of one-step "
                "prediction of the measured speed. Log scale.",
                "RMSE per model and roller",
            ),
        )
    notes = _rel_notes(results)
    if notes:
        parts.append(para("Relative errors omitted: " + "; ".join(notes) + ".", cls="note"))
    if extra:
        parts.append(
            para(
                f"Extra variants ({', '.join(label(e) for e in extra)}) are reported "
                "separately and are not part of the best-value highlighting: MD-S-L+d "
                "also sees the current disagreement ŷ_d(t) − ŷ_m(t) of the data-driven "
                "and mechanistic models.",
                cls="note",
            )
        )
    return section("comparison", "2. Model comparison (Table 2 analogue)", *parts)


def figures_section(figs: Mapping[str, bytes], models: list[str], zoom: tuple[float, float],
                    truth: bool = True) -> Raw:  # fmt: skip
    """Section 3: measured vs predicted, residuals and their spectra (Fig. 8 analogue)."""
    names = ", ".join(label(m) for m in models)
    parts = [
        figure(
            figs["predictions"],
            "fig-predictions",
            join(
                [
                    "Measured vs predicted speed per roller (",
                    names,
                    "). Left: the whole test part; right: a zoom on ",
                    f"{zoom[0]:.1f}–{zoom[1]:.1f} s",
                    ", with the plant's true speed dotted." if truth else ".",
                ]
            ),
            "measured and predicted roller speeds",
        ),
        figure(
            figs["residuals"],
            "fig-residuals",
            "Residuals (measured − predicted) per roller and their power spectra (Welch). "
            "A flat (white) residual spectrum is the best a one-step predictor can leave; "
            "peaks are periodic dynamics (eccentricity, mesh) that a model misses.",
            "residuals and spectra",
        ),
    ]
    return section("predictions", "3. Predictions and residuals (Fig. 8 analogue)", *parts)
