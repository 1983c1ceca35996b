"""The report's first screen: the headline figure (each model's test RMSE per roller beside
the floor, persistence, the physics and the paper's ranking) and the verdict table (one row per
question of the paper: ours, the paper's, and whether they agree, with a link to the section).

Every verdict is computed from the results by the rules of :mod:`drafttwin.report.agreement`
(stated on the page as :data:`RULE`); no outcome is written here.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from drafttwin._constants import ROLLERS
from drafttwin.report import agreement, figures, paper
from drafttwin.report.agreement import label
from drafttwin.report.fmt import count_text, is_num, span
from drafttwin.report.html import Cell, Raw, Row, figure, join, para, table, tag
from drafttwin.report.overview import ours_label
from drafttwin.report.tables import compared_models, metric_unit, paper_table2

NOT_RUN = "not run"
INDICATIVE = "indicative only"
"""The verdict of a check run on the quick benchmark's tiny networks (no colour)."""
RULE = (
    "How the verdicts are computed: each question is answered per roller, in our results and "
    "in the paper's tables. “agrees”: both point the same way on every roller; “partly”: on "
    "some; “does not agree”: on none. Model comparisons use the paper's metric (mean relative "
    "error); an ablation difference counts only where it exceeds the spread of the repeated "
    "tests; “does the physics pay” counts the hard free runs in which the physics and a hybrid "
    "both beat the GRU on every roller (the premise of a hybrid; the paper does not measure "
    "it)."
)
REFERENCES = {
    "floor": "floor (no one-step predictor can go lower)",
    "persistence": "persistence (repeat the last measurement)",
    "mechanistic": "physics alone (nominal model)",
}


@dataclass(frozen=True)
class Verdict:
    """One row of the verdict table."""

    question: str
    compared: str
    ours: str
    paper: str
    verdict: str
    href: str
    where: str


def _beats_row(results: Mapping[str, Any], b: str, question: str) -> Verdict:
    """MD-S-L against model ``b`` (the paper's Table 2)."""
    d = agreement.beats_directions(results, "md-s-l", b)
    by_rmse = [r for r in ROLLERS if _rmse(results, "md-s-l", r) < _rmse(results, b, r)]
    tied = [r for r in ROLLERS if paper_table2("md-s-l", r)[1] == paper_table2(b, r)[1]]
    theirs = f"lower mean rel. error on {count_text(d.paper)}"
    theirs += f"; equal on {', '.join(tied)}" if tied else ""
    ours = f"lower mean rel. error on {count_text(d.ours)}; lower RMSE on {count_text(by_rmse)}"
    compared = f"MD-S-L vs {label(b)}, test part"
    return Verdict(question, compared, ours, theirs, agreement.verdict(len(d.same)),
                   "#comparison", "§2 comparison")  # fmt: skip


def _rmse(results: Mapping[str, Any], model: str, roller: str) -> float:
    v = results["comparison"]["metrics"][model][roller].get("rmse")
    return float(v) if is_num(v) else float("nan")


def _ablation_row(results: Mapping[str, Any], b: str, question: str) -> Verdict:
    """MD-S-L against the variant ``b`` without one part (the paper's Table 3)."""
    d = agreement.ablation_directions(results, "md-s-l", b)
    diffs = span(agreement.ablation_diffs(results, "md-s-l", b), 4, " points")
    theirs = f"more accurate on {count_text(d.paper)}, by "
    theirs += span(agreement.paper_ablation_diffs("md-s-l", b), 2, " points")
    ours = f"more accurate beyond the spread on {count_text(d.ours)}; difference {diffs}"
    n = len(results["ablation"].get("seeds", []))
    compared = f"MD-S-L vs {label(b)}, {n} repeated tests"
    return Verdict(question, compared, ours, theirs, agreement.verdict(len(d.same)),
                   "#ablation", "§5 ablation")  # fmt: skip


def _physics_row(results: Mapping[str, Any]) -> Verdict:
    """The generalisation benchmark's checks: hard free runs away from the training point."""
    question = "Does the physics pay away from the training point?"
    compared = "physics and hybrids vs the GRU, free runs"
    doc = results.get("generalisation")
    theirs = "not measured (the premise of a hybrid)"
    if not doc or not doc.get("checks"):
        return Verdict(question, compared, "not run (--no-generalisation)", theirs, NOT_RUN,
                       "#agreement", "§6 agreement")  # fmt: skip
    checks = doc["checks"]
    held = [c["scenario"] for c in checks if c["holds"]]
    runs = ", ".join(c["scenario"] for c in checks)
    ours = (f"physics and a hybrid beat the GRU on every roller in {len(held)} of "
            f"{len(checks)} hard free runs ({runs})")  # fmt: skip
    said = agreement.verdict(len(held), len(checks))
    if doc.get("config", {}).get("name") == "quick":
        # a smoke test (2-epoch networks of 8 units) answers no question: it only points
        ours += "; quick benchmark (tiny networks): a smoke test, not evidence"
        said = INDICATIVE
    return Verdict(question, compared, ours, theirs, said, "#generalisation", "physics pays")


def verdicts(results: Mapping[str, Any]) -> list[Verdict]:
    """The verdict table's rows: the questions the results can answer, in the paper's order."""
    models = compared_models(results)[0]
    variants = list(results.get("ablation", {}).get("variants", []))
    rows = []
    if {"md-s-l", "parallel"} <= set(models):
        rows.append(_beats_row(results, "parallel", "Is MD-S-L more accurate than the parallel "
                                                    "hybrid?"))  # fmt: skip
    if {"md-s-l", "gru"} <= set(models):
        rows.append(_beats_row(results, "gru", "Is MD-S-L more accurate than the data-driven "
                                               "GRU?"))  # fmt: skip
    if {"md-s-l", "md-l"} <= set(variants):
        rows.append(_ablation_row(results, "md-l", "Does the SKNet help?"))
    if {"md-s-l", "md-s"} <= set(variants):
        rows.append(_ablation_row(results, "md-s", "Does the LSTM help?"))
    rows.append(_physics_row(results))
    return rows


def verdict_table(rows: list[Verdict], ours: str = "ours (plant emulator)") -> Raw:
    """The verdict table (id ``verdicts``); ``ours``: our column's heading."""
    head: list[Row] = [[Cell("question", header=True, cls="name"), ours,
                        "paper (real FA320A)", "verdict", "details"]]  # fmt: skip
    body: list[Row] = [
        [
            Cell(join([v.question, tag("span", v.compared, cls="pair")]), cls="q"),
            Cell(v.ours, cls="wrap"),
            Cell(v.paper, cls="wrap"),
            Cell(v.verdict, cls="verdict v-" + v.verdict.replace(" ", "-")),
            Cell(tag("a", v.where, href=v.href), cls="name"),
        ]
        for v in rows
    ]
    return table(head, body, id="verdicts", cls="verdicts")


def _ordinal(n: int) -> str:
    return f"{n}{'st' if n == 1 else 'nd' if n == 2 else 'rd' if n == 3 else 'th'}"


def paper_rank(model: str, roller: str) -> str:
    """The model's rank in the paper's Table 2 on ``roller`` (mean relative error; ties
    share a rank, marked ``=``): ``"paper 1st"``, ``"paper =1st"``, or ``"not in paper"``."""
    mine = paper_table2(model, roller)[1]
    if not is_num(mine):
        return "not in paper"
    others = [paper_table2(m, roller)[1] for m in paper.TABLE2 if m != model]
    rank = 1 + sum(o < mine for o in others)
    return f"paper {'=' if mine in others else ''}{_ordinal(rank)}"


def headline_png(results: Mapping[str, Any]) -> bytes:
    """The headline figure from the comparison's metrics."""
    main = compared_models(results)[0]
    learned = [m for m in main if m not in REFERENCES]
    metrics = results["comparison"]["metrics"]
    rmse = {label(m): [_rmse(results, m, r) for r in ROLLERS] for m in learned}
    floor = [metrics[main[0]][r].get("rmse_floor") for r in ROLLERS]
    refs = {REFERENCES["floor"]: [float(f) if is_num(f) else float("nan") for f in floor]}
    refs |= {REFERENCES[m]: [_rmse(results, m, r) for r in ROLLERS]
             for m in ("persistence", "mechanistic") if m in main}  # fmt: skip
    notes = {label(m): [paper_rank(m, r) for r in ROLLERS] for m in learned}
    colors = {label(m): figures.COLORS.get(m) for m in learned}
    return figures.headline_rmse(rmse, refs, notes, colors, unit=metric_unit(results))


def glance_section(results: Mapping[str, Any], png: bytes) -> Raw:
    """The first screen: the headline figure, the verdict table and the rule behind it."""
    unit = metric_unit(results) or "the signal's unit"
    caption = join([
        f"Test RMSE per roller ({unit}, log scale; lower is better), one-step-ahead "
        "predictions. Above each dot: its rank in the paper's Table 2 (mean relative error, "
        "real FA320A). Every model in numbers: ",
        tag("a", "§2", href="#comparison"), ".",
    ])  # fmt: skip
    return tag(
        "section",
        join(
            [
                tag("h2", "At a glance: does the study agree with the paper?"),
                figure(png, "fig-headline", caption, "test RMSE per model and roller"),
                verdict_table(verdicts(results), ours_label(results)),
                para(
                    join([RULE, " All claims: ", tag("a", "§6", href="#agreement"), "."]),
                    cls="note",
                ),
            ]
        ),  # fmt: skip
        id="glance",
        cls="glance",
    )
