"""Agreement with the paper, computed from the numbers (nothing is hard-coded).

Each :class:`Claim` states a question the paper answers, what the paper's own tables show,
what our study shows, and a verdict derived from per-roller counts: ``"agrees"`` when our
numbers point the same way as the paper's on every roller, ``"does not agree"`` on none,
``"partly"`` otherwise; ``"not in paper"`` for questions the paper does not ask.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from drafttwin._constants import ROLLERS
from drafttwin.report import paper
from drafttwin.report.fmt import count_text, is_num, num, span
from drafttwin.report.tables import metric_unit, paper_table2, paper_table3_stats

AGREES, PARTLY, DISAGREES, NOT_IN_PAPER = "agrees", "partly", "does not agree", "not in paper"
LABELS = {
    "mechanistic": "mechanistic model",
    "persistence": "persistence",
    "gru": "GRU (data-driven)",
    "parallel": "parallel hybrid",
    "md-s-l": "MD-S-L",
    "md-s-l+d": "MD-S-L+d",
    "md-l": "MD-L",
    "md-s": "MD-S",
}


@dataclass(frozen=True)
class Claim:
    """One comparison with the paper: the claim, the paper's and our evidence, a verdict."""

    topic: str
    paper: str
    ours: str
    verdict: str
    key: str = ""


def label(model: str) -> str:
    """The display name of a model or variant."""
    return LABELS.get(model, model)


def verdict(n_ok: int, n_total: int = len(ROLLERS)) -> str:
    """``agrees`` / ``partly`` / ``does not agree`` from how many rollers support a claim."""
    if n_ok == n_total:
        return AGREES
    return DISAGREES if n_ok == 0 else PARTLY


def _metric(results: Mapping[str, Any], model: str, roller: str, key: str) -> float:
    value = results["comparison"]["metrics"][model][roller].get(key)
    return float(value) if is_num(value) else float("nan")


def _lower(results: Mapping[str, Any], a: str, b: str, key: str) -> list[str]:
    """Rollers on which model ``a`` has a strictly lower ``key`` than model ``b``."""
    return [r for r in ROLLERS if _metric(results, a, r, key) < _metric(results, b, r, key)]


def _paper_lower(a: str, b: str) -> tuple[list[str], list[str]]:
    """Rollers where the paper's mean relative error of ``a`` is lower / equal to ``b``'s."""
    lower, tied = [], []
    for r in ROLLERS:
        ma, mb = paper_table2(a, r)[1], paper_table2(b, r)[1]
        if ma < mb:
            lower.append(r)
        elif ma == mb:
            tied.append(r)
    return lower, tied


@dataclass(frozen=True)
class Directions:
    """A claim per roller: where ours supports it, where the paper's does, where both point
    the same way (supported in both, or in neither)."""

    ours: list[str]
    paper: list[str]
    same: list[str]


def _directions(ours: list[str], paper_side: list[str]) -> Directions:
    same = [r for r in ROLLERS if (r in ours) == (r in paper_side)]
    return Directions(ours, paper_side, same)


def beats_directions(results: Mapping[str, Any], a: str, b: str) -> Directions:
    """Rollers where ``a`` has the lower mean relative error than ``b``: ours and the
    paper's Table 2 (the paper's metric)."""
    return _directions(_lower(results, a, b, "mean_rel_err_pct"), _paper_lower(a, b)[0])


def beats(results: Mapping[str, Any], a: str, b: str) -> Claim:
    """Is model ``a`` more accurate than ``b`` per roller, by RMSE and mean relative error?

    The verdict compares directions with the paper's Table 2 on its own metric: a roller
    agrees when ``a`` has the lower mean relative error in both, or in neither.
    """
    by_rmse = _lower(results, a, b, "rmse")
    d = beats_directions(results, a, b)
    p_tied = _paper_lower(a, b)[1]
    paper_text = f"lower mean relative error on {count_text(d.paper)}"
    if p_tied:
        paper_text += f", equal on {', '.join(p_tied)}"
    ours = f"lower RMSE on {count_text(by_rmse)}, lower mean relative error on {count_text(d.ours)}"
    if 0 < len(d.same) < len(ROLLERS):
        ours += f"; same direction as the paper on {count_text(d.same)}"
    topic = f"{label(a)} more accurate than the {label(b)}?"
    return Claim(topic, paper_text, ours, verdict(len(d.same)), key=f"{a}>{b}")


def skill_claim(results: Mapping[str, Any], models: list[str]) -> Claim:
    """Which models beat the naive persistence forecast (skill > 0), per roller."""
    parts = []
    for m in models:
        if m == "persistence":
            continue
        ok = [r for r in ROLLERS if _metric(results, m, r, "skill") > 0]
        skills = [_metric(results, m, r, "skill") for r in ROLLERS]
        parts.append(f"{label(m)} on {count_text(ok)} (skill {span(skills, 3)})")
    return Claim(
        "Which models beat persistence (skill > 0)?",
        "no persistence row: not tested",
        "; ".join(parts),
        NOT_IN_PAPER,
        key="skill",
    )


def _best_of(results: Mapping[str, Any], models: list[str], roller: str, key: str) -> str:
    """The model with the lowest finite ``key`` on ``roller``; '' if none."""
    finite = {m: v for m in models if is_num(v := _metric(results, m, roller, key))}
    return min(finite, key=finite.__getitem__) if finite else ""


def _limits_text(results: Mapping[str, Any], models: list[str], roller: str) -> str:
    """One roller's best one-step RMSE against its floor, and its best estimate of the true
    speed against the encoders' error."""
    unit = metric_unit(results)
    best = _best_of(results, models, roller, "rmse")
    if not best:
        return ""
    rmse, floor = (
        _metric(results, best, roller, "rmse"),
        _metric(results, best, roller, "rmse_floor"),
    )
    text = f"{roller}: {label(best)} {num(rmse, 3)} {unit}".replace("  ", " ")
    if not is_num(floor) or floor <= 0:
        return text + " (floor unknown: no true speed)"
    below = [label(m) for m in models if _metric(results, m, roller, "rmse")
             < _metric(results, m, roller, "rmse_floor")]  # fmt: skip
    text += f" = {rmse / floor:.2f} × the floor {num(floor, 3)}"
    if below:  # the floor is then not a floor: say so, never hide it
        text += f" (BELOW the floor: {', '.join(below)}; the floor is wrong)"
    est = _best_of(results, models, roller, "rmse_vs_true")
    if est:
        ratio = _metric(results, est, roller, "true_error_ratio")
        vs_true = f"{num(_metric(results, est, roller, 'rmse_vs_true'), 3)} {unit}".strip()
        text += (f"; true speed best estimated by {label(est)}, {vs_true} = {ratio:.2f} × "
                 "the encoder's error")  # fmt: skip
    return text


def limits_claim(results: Mapping[str, Any], models: list[str]) -> Claim:
    """How close the best one-step RMSE per roller comes to the floor (the lowest RMSE any
    predictor of the measured speed can reach), and how the best estimate of the true speed
    compares with the encoders' own error."""
    parts = [t for r in ROLLERS if (t := _limits_text(results, models, r))]
    return Claim(
        "How close does the best RMSE come to the floor, and is the twin a better speed "
        "sensor than the encoder?",
        "not reported",
        "; ".join(parts) or "no finite RMSE",
        NOT_IN_PAPER,
        key="floor",
    )


def magnitude_claim(results: Mapping[str, Any], model: str) -> Claim:
    """Our mean relative errors of ``model`` against the paper's, as a range and a ratio."""
    ours = [_metric(results, model, r, "mean_rel_err_pct") for r in ROLLERS]
    theirs = [paper_table2(model, r)[1] for r in ROLLERS]
    ratios = [o / t for o, t in zip(ours, theirs, strict=True) if is_num(o) and is_num(t) and t > 0]
    close = [
        r
        for r, o, t in zip(ROLLERS, ours, theirs, strict=True)
        if is_num(o) and is_num(t) and t / 3 <= o <= 3 * t
    ]
    text = f"{span(ours, 4, ' %')}"
    if ratios:
        text += f" ({span(ratios, 2)} × the paper's; within a factor 3 on {count_text(close)})"
    return Claim(
        f"Is the {label(model)}'s mean relative error of the paper's size?",
        span(theirs, 3, " %"),
        text,
        verdict(len(close)),
    )


def _diff(results: Mapping[str, Any], a: str, b: str, roller: str) -> tuple[float, bool] | None:
    """(mean accuracy of a minus b, larger than spread) from the study's differences."""
    for d in results["ablation"].get("differences", []):
        if d["roller"] != roller or d.get("metric", "accuracy_pct") != "accuracy_pct":
            continue
        if (d["a"], d["b"]) == (a, b):
            return float(d["mean_diff"]), bool(d["larger_than_spread"])
        if (d["a"], d["b"]) == (b, a):
            return -float(d["mean_diff"]), bool(d["larger_than_spread"])
    return None


def ablation_diffs(results: Mapping[str, Any], a: str, b: str) -> list[float]:
    """Our mean accuracy of ``a`` minus ``b`` per roller (points), where the study has it."""
    return [d[0] for r in ROLLERS if (d := _diff(results, a, b, r)) is not None]


def paper_ablation_diffs(a: str, b: str) -> list[float]:
    """The paper's Table 3 mean accuracy of ``a`` minus ``b`` per roller (points)."""
    return [paper_table3_stats(r, a)[0] - paper_table3_stats(r, b)[0] for r in ROLLERS]


def ablation_directions(results: Mapping[str, Any], a: str, b: str) -> Directions:
    """Rollers where ``a`` is more accurate than ``b``: ours by more than the spread of the
    repeats, the paper's by its Table 3 means (whose differences all exceed its spread)."""
    beyond = [r for r in ROLLERS if (x := _diff(results, a, b, r)) and x[0] > 0 and x[1]]
    p_higher = [r for r, d in zip(ROLLERS, paper_ablation_diffs(a, b), strict=True) if d > 0]
    return _directions(beyond, p_higher)


def ablation_claim(results: Mapping[str, Any], a: str, b: str, what: str) -> Claim:
    """Is variant ``a`` more accurate than ``b`` by more than the spread of the repeats?

    A roller agrees with the paper when ``a`` is higher by more than the spread in ours and
    higher in the paper's Table 3 (whose differences all exceed its test-to-test spread), or
    neither.
    """
    higher = [r for r in ROLLERS if (x := _diff(results, a, b, r)) and x[0] > 0]
    d = ablation_directions(results, a, b)
    p_std = [paper_table3_stats(r, v)[1] for r in ROLLERS for v in (a, b)]
    paper_text = (
        f"{label(a)} higher accuracy on {count_text(d.paper)}, by "
        f"{span(paper_ablation_diffs(a, b), 2)} points (test-to-test std {span(p_std, 3)})"
    )
    ours = (
        f"{label(a)} higher on {count_text(higher)}, by {span(ablation_diffs(results, a, b), 4)} "
        f"points; larger than the spread on {count_text(d.ours)}"
    )
    return Claim(what, paper_text, ours, verdict(len(d.same)), key=f"{a}>{b}")


def claims(results: Mapping[str, Any]) -> list[Claim]:
    """All comparisons with the paper that the study's numbers allow."""
    models = list(results["comparison"]["models"])
    out: list[Claim] = []
    pairs = [
        ("md-s-l", "parallel"),
        ("md-s-l", "gru"),
        ("parallel", "mechanistic"),
        ("gru", "mechanistic"),
    ]
    out += [beats(results, a, b) for a, b in pairs if a in models and b in models]
    if "persistence" in models:
        out.append(skill_claim(results, models))
    out.append(limits_claim(results, models))
    out += [magnitude_claim(results, m) for m in ("mechanistic", "md-s-l") if m in models]
    variants = list(results.get("ablation", {}).get("variants", []))
    tests: list[tuple[str, str, str]] = [
        ("md-s-l", "md-l", "Does removing the SKNet (MD-L) lower the accuracy?"),
        ("md-s-l", "md-s", "Does removing the LSTM (MD-S) lower the accuracy?"),
        ("md-l", "md-s", "Is MD-L more accurate than MD-S?"),
    ]
    out += [
        ablation_claim(results, a, b, t) for a, b, t in tests if a in variants and b in variants
    ]
    return out


INCONSISTENCY = paper.INCONSISTENCY
