"""Sections 4 to 6 of the report: grid search (Fig. 7 analogue), ablation (Table 3 analogue)
and the agreement with the paper."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from drafttwin._constants import ROLLERS
from drafttwin.report import agreement, paper
from drafttwin.report.agreement import label
from drafttwin.report.fmt import DASH, is_num, num, sig, sig_fixed
from drafttwin.report.html import Cell, bullets, figure, join, kv_table, para, section, table, tag
from drafttwin.report.overview import ours_label
from drafttwin.report.tables import paper_table3_stats

if TYPE_CHECKING:
    from drafttwin.report.html import BodyRow, CellLike, Raw, Row

CONFIG_KEYS = ("lr", "hidden", "layers")


def _grid_matrix(rows: list[Mapping[str, Any]], net: str) -> Raw:
    """Validation loss as (hidden, layers) rows × learning-rate columns; best in green."""
    lrs = sorted({r["lr"] for r in rows})
    combos = sorted({(r["hidden"], r["layers"]) for r in rows})
    losses = {(r["lr"], r["hidden"], r["layers"]): r["val_loss"] for r in rows}
    finite = {k: v for k, v in losses.items() if is_num(v)}
    best = min(finite, key=finite.__getitem__) if finite else None
    body = []
    for h, nl in combos:
        cells: list[CellLike] = [Cell(f"hidden {h}, {nl} layers", cls="name")]
        for lr in lrs:
            key = (lr, h, nl)
            cells.append(Cell(sig(losses.get(key), 3), cls="best" if key == best else None))
        body.append(cells)
    head: list[Row] = [[Cell(net.upper(), header=True, cls="name"), *[f"lr {lr:g}" for lr in lrs]]]
    return table(head, body, id=f"grid-{net}")


def _best_configs(grid: Mapping[str, Any]) -> Raw:
    body: list[Row] = []
    for net in ("lstm", "gru"):
        ours = grid.get("best", {}).get(net, {})
        theirs = paper.FIG7_BEST.get(net, {})
        same = all(ours.get(k) == theirs.get(k) for k in CONFIG_KEYS) and bool(ours)
        body.append(
            [
                Cell(net.upper(), cls="name"),
                *[sig(ours.get(k), 3) for k in CONFIG_KEYS],
                sig(ours.get("val_loss"), 3),
                *[sig(theirs.get(k), 3) for k in CONFIG_KEYS],
                sig(theirs.get("loss"), 3),
                Cell("yes" if same else "no", cls="yes" if same else "no"),
            ]
        )
    head: list[Row] = [
        [
            Cell("network", header=True, rowspan=2, cls="name"),
            Cell("ours (best of the grid)", header=True, colspan=4),
            Cell("paper (Fig. 7, real FA320A)", header=True, colspan=4),
            Cell("same configuration", header=True, rowspan=2),
        ],
        ["lr", "hidden", "layers", "val. loss", "lr", "hidden", "layers", "loss"],
    ]
    return table(head, body, id="grid-best")


def grid_section(results: Mapping[str, Any], figs: Mapping[str, bytes]) -> Raw:
    """Section 4: grid-search losses, best configurations vs the paper's, the budget."""
    grid, prof = results["grid"], results["profile"].get("name", DASH)
    budget = grid.get("budget", {})
    epochs = budget.get("epochs")
    if prof == "paper" and not (is_num(epochs) and epochs < 500):
        budget_text = "The paper profile trains every configuration with the paper's settings."
    else:
        budget_text = (
            f"The {prof} profile uses a reduced grid budget (below); the paper trained every "
            "configuration for 500 epochs with batch 10. Our losses rank the configurations "
            "after this shorter training, so the best configuration may differ from the one "
            "a full training would pick."
        )
    parts: list[Raw | str] = [
        para(
            "Learning rate {0.001, 0.005, 0.01} × hidden size {64, 128, 256} × layers {2, 3} "
            "for the LSTM and the GRU, trained on the training part; criterion: validation "
            "loss (MSE on min-max-scaled speeds). Loss values depend on the data and its "
            "scaling, so only the ranking, not the absolute loss, compares with the paper's."
        ),
        figure(
            figs["grid"],
            "fig-grid",
            "Validation loss of every grid configuration "
            "(log scale), per network: the Fig. 7 analogue.",
            "grid-search losses",
        ),
        tag("h3", "Best configurations"),
        _best_configs(grid),
        tag("h3", "Validation losses"),
        join(
            [_grid_matrix(list(grid.get(net, [])), net) for net in ("lstm", "gru") if grid.get(net)]
        ),
        tag("h3", "Grid budget"),
        para(budget_text),
        kv_table(budget, id="grid-budget") if budget else para("No budget recorded."),
    ]
    return section("grid", "4. Grid search (Fig. 7 analogue)", *parts)


def _table3_html(abl: Mapping[str, Any]) -> Raw:
    variants = list(abl["variants"])
    acc = {v: np.asarray(abl["accuracy"][v], dtype=float) for v in variants}
    summ = abl["summary"]
    head: list[Row] = [
        [
            Cell("test", header=True, rowspan=2),
            Cell("seed", header=True, rowspan=2),
            *[Cell(f"{r} roller", header=True, colspan=len(variants)) for r in ROLLERS],
        ],
        [label(v) for _ in ROLLERS for v in variants],
    ]
    body: list[BodyRow] = []
    for i, seed in enumerate(abl["seeds"]):
        body.append(
            [
                str(i + 1),
                str(seed),
                *[num(acc[v][i, j], 4) for j in range(len(ROLLERS)) for v in variants],
            ]
        )

    def best_variant(roller: str) -> str:
        best: str = max(variants, key=lambda v: summ[v][roller]["mean"])
        return best

    best = {r: best_variant(r) for r in ROLLERS}
    for title, key in (("ours: mean", "mean"), ("ours: std", "std"), ("ours: min", "min"),
                       ("ours: max", "max")):  # fmt: skip
        cells: list[CellLike] = [Cell(title, colspan=2, cls="name")]
        for r in ROLLERS:
            for v in variants:
                x = summ[v][r][key]
                text = sig_fixed(x, 2) if key == "std" else num(x, 4)
                cells.append(Cell(text, cls="best" if key == "mean" and best[r] == v else None))
        body.append(("summary", cells))
    for title, k in (("paper: mean", 0), ("paper: std", 1)):
        cells = [Cell(title, colspan=2, cls="name")]
        cells += [num(paper_table3_stats(r, v)[k], 3) for r in ROLLERS for v in variants]
        body.append(("paper", cells))
    return table(head, body, id="table3")


def _paper_table3() -> Raw:
    head = [["test", *[f"{r}: {label(v)}" for r in ROLLERS for v in paper.TABLE3_VARIANTS]]]
    body = [
        [
            str(i + 1),
            *[
                f"{paper.TABLE3[r][i][k]:.2f}"
                for r in ROLLERS
                for k in range(len(paper.TABLE3_VARIANTS))
            ],
        ]
        for i in range(len(paper.TABLE3[ROLLERS[0]]))
    ]
    return table(head, body, id="table3-paper")


def _differences_html(abl: Mapping[str, Any]) -> Raw:
    """Pairwise differences from the study; a Welch p column when the study gives one."""
    diffs = list(abl.get("differences", []))
    with_p = any("welch_p" in d for d in diffs)
    body = []
    for d in diffs:
        pa, pb = (paper_table3_stats(d["roller"], d[k])[0] for k in ("a", "b"))
        yes = bool(d["larger_than_spread"])
        row: list[CellLike] = [Cell(f"{label(d['a'])} − {label(d['b'])}", cls="name"),
                     Cell(d["roller"], cls="name"), num(d.get("mean_diff"), 4),
                     sig(d.get("spread"), 2), Cell("yes" if yes else "no", cls="yes" if yes else "no")]  # fmt: skip
        if with_p:
            row.append(sig(d.get("welch_p"), 2))
        body.append([*row, num(pa - pb, 3)])
    head: list[Row] = [[Cell("pair (a − b)", header=True, cls="name"), Cell("roller", header=True, cls="name"),
             "mean difference (points)", "spread (points)", "difference larger than spread",
             *(["Welch t-test p"] if with_p else []), "paper: mean difference"]]  # fmt: skip
    return table(head, body, id="differences")


def _shared_text(shared: Any) -> str:
    if shared is None:
        return ""
    if shared:
        return "The repeated tests share one data-driven model; the seed varies the residual model."
    return "Each repeated test refits the whole model, data-driven part included."


def ablation_section(results: Mapping[str, Any], figs: Mapping[str, bytes]) -> Raw:
    """Section 5: ablation accuracy per test and roller, summary, spread, differences."""
    abl = results["ablation"]
    spread_def = abl.get("spread_definition") or (
        "the spread of the repeated tests, as computed by the study"
    )
    variants = ", ".join(label(v) for v in abl["variants"])
    parts: list[Raw | str] = [
        para(
            f"Prediction accuracy (100 − mean relative error, %) of {variants} over "
            f"{len(abl['seeds'])} repeated tests (one seed each). MD-L drops the SKNet, MD-S "
            f"drops the LSTM. {_shared_text(abl.get('shared_data_model'))}"
        ),
        figure(
            figs["ablation"],
            "fig-ablation",
            f"Accuracy of each variant in each of the {len(abl['seeds'])} repeated tests (dots) "
            "and their mean ± one standard deviation (bar), per roller; crosses: the paper's "
            "means, on the right axis (its own scale).",
            "ablation accuracy per test",
        ),
        _table3_html(abl),
        tag(
            "details",
            join(
                [tag("summary", "The paper's Table 3, test by test (real FA320A)"), _paper_table3()]
            ),
        ),
        tag("h3", "Are the differences larger than the spread?"),
        para(
            join(
                [
                    "Spread: ",
                    spread_def,
                    ". A difference smaller than the spread cannot be told "
                    "apart from the seed-to-seed variation.",
                ]
            )
        ),
        _differences_html(abl),
    ]
    return section("ablation", "5. Ablation (Table 3 analogue)", *parts)


def agreement_section(results: Mapping[str, Any]) -> Raw:
    """Section 6: each paper claim against our numbers, the paper's inconsistency, findings."""
    body = [
        [
            Cell(c.topic, cls="wrap"),
            Cell(c.paper, cls="wrap"),
            Cell(c.ours, cls="wrap"),
            Cell(c.verdict, cls="v-" + c.verdict.replace(" ", "-")),
        ]
        for c in agreement.claims(results)
    ]
    head: list[Row] = [
        [
            Cell("claim", header=True, cls="wrap"),
            Cell("paper (real FA320A)", header=True),
            Cell(ours_label(results), header=True),
            "verdict",
        ]
    ]
    parts: list[Raw | str] = [
        para(
            "Computed from the numbers above. Each question is answered per roller; the verdict "
            "is “agrees” when our answer and the paper's point the same way on all four "
            "rollers, “does not agree” when on none, “partly” otherwise. Model comparisons use "
            "the paper's metric (mean relative error) for the verdict, and report RMSE beside "
            "it; ablation differences count only where they exceed the spread of the repeated "
            "tests; sizes agree within a factor of 3. Agreement in trend on emulated data is not "
            "a replication on a real machine."
        ),
        table(head, body, id="agreement"),
        tag("h3", "A note on the paper's own numbers"),
        tag("div", para(agreement.INCONSISTENCY), cls="paperbox"),
    ]
    findings = results.get("findings") or []
    if findings:
        parts += [tag("h3", "Findings of the study"), bullets([str(f) for f in findings])]
    return section("agreement", "6. Agreement with the paper", *parts)
