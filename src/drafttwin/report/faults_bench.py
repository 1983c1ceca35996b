"""The fault benchmark's HTML page: the score table per method and the confusion matrix."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from drafttwin.report.html import Cell, join, page, para, section, table, tag


def _f(x: Any, digits: int = 1) -> str:
    if x is None:
        return "-"
    return f"{x:.{digits}f}" if isinstance(x, float) else str(x)


def score_rows(scores: Mapping[str, Mapping[str, Any]]) -> list[list[str]]:
    rows = []
    for method, s in scores.items():
        loc = s.get("localisation") or {}
        det = s["detection_pct"]
        rows.append([method, _f(det["light"]), _f(det["moderate"]), _f(det["severe"]),
                     _f(s["detection_pct_not_assessed"]),
                     _f(s["delay_step_s"]["median"]), _f(s["delay_step_s"]["p90"]),
                     _f(s["delay_ramp_s"]["median"]),
                     f"{s['false_alarms']} in {s['healthy_hours']:.2f} h",
                     _f(s["false_alarms_per_24h_upper95"]),
                     _f(loc.get("top1_pct")), _f(loc.get("top3_pct")), _f(loc.get("group_hit_pct")),
                     _f(loc.get("severity_rel_error_median"), 2),
                     _f(loc.get("sensor_blamed_on_machine"))])  # fmt: skip
    return rows


HEAD = ["method", "detected % light", "moderate", "severe", "not assessed",
        "delay step median s", "p90 s", "delay ramp median s", "false alarms",
        "per 24 h (95 % bound)", "top-1 %", "top-3 %", "group hit %", "severity error",
        "sensor blamed on machine"]  # fmt: skip


def confusion_table(conf: Mapping[str, Mapping[str, int]]) -> Any:
    cols = sorted({p for row in conf.values() for p in row})
    body = []
    for kind, row in conf.items():
        total = max(1, sum(row.values()))
        cells: list[Any] = [Cell(kind, header=True)]
        for c in cols:
            n = row.get(c, 0)
            cls = "best" if c == kind and n else ("no" if n and c != kind else None)
            cells.append(Cell(str(n) if n else "", cls=cls, title=f"{100 * n / total:.0f} %"))
        body.append(cells)
    return table([["true \\ first cause", *cols]], body, id="confusion")


def _learned_note(learned: Mapping[str, Any]) -> str:
    parts = [f"{name}: {d['model']} ({d['task']}), fitted on the tuning records in "
             f"{d['fit_s']:.1f} s, {d['epochs']} epochs, best validation loss {_f(d['val_loss'], 5)}"
             for name, d in learned.items() if isinstance(d, dict) and "model" in d]  # fmt: skip
    return (
        f"window {learned['window']} samples, hidden {learned['hidden']}, "
        f"{learned['layers']} layer; " + "; ".join(parts) + ". The data-driven residual is "
        "a one-step innovation (a persistent change enters its input window), so it is "
        "not localised; the hybrid's prediction comes from the set-points only"
        + _hybrid_kept(learned.get("hybrid", {}).get("correction"))
        + "."
    )


_KEPT = {
    "none": "no correction: it predicts the physics itself, so its column is the physics'",
    "offset": "the measured offset held (no network): a constant each record's baseline removes",
}


def _hybrid_kept(correction: Mapping[str, Any] | None) -> str:
    """What the hybrid's validation folds kept, in words (older results: nothing said)."""
    if not correction or "kept" not in correction:
        return ""
    kept = str(correction["kept"])
    said = _KEPT.get(kept, f"its network's correction ({kept})")
    folds = correction.get("chosen_fold_nrmse") or []
    scores = ", ".join(_f(v, 3) for v in folds)
    return f"; its validation folds kept {said}" + (f" (fold NRMSE {scores})" if scores else "")


def _subtitle(results: Mapping[str, Any]) -> str:
    """'plan full, seed 0: 4 tuning, 78 fault and 12 healthy records (0.4 / 0.9 / 2.1 h of
    machine time), 11 min 11 s wall' in words, not as a dict."""
    sets, secs = results["sets"], results["machine_seconds"]
    names = [n for n in ("tuning", "faults", "healthy") if n in sets]
    counts = ", ".join(f"{sets[n]} {'fault' if n == 'faults' else n}" for n in names)
    hours = " / ".join(f"{secs.get(n, 0.0) / 3600:.2g}" for n in names)
    wall = float(results["wall_s"])
    return (
        f"plan {results.get('plan', results.get('profile'))}, seed {results['seed']}: {counts} records ({hours} h "
        f"of machine time), {int(wall // 60)} min {wall % 60:.0f} s wall"
    )


def render_benchmark(results: Mapping[str, Any]) -> str:
    scores = results["scores"]
    body = join([
        tag("h1", "Fault benchmark"),
        para(_subtitle(results), cls="sub"),
        section("scores", "Scores per method", table([HEAD], score_rows(scores), id="scores"),
                para("Detection and delays count faults whose kind moves the mean speeds or the "
                     "rollers' angles (gear wear, chain elongation); gear crack and run-out and "
                     "roller run-out are the 'not assessed' column. Localisation is scored on moderate and severe faults the "
                     "method detected (physics and hybrid: the physics ranking of the shift after "
                     "their own alarm); a group hit means the truth is among the causes "
                     "these sensors cannot tell apart from the first.", cls="note")),
        section("confusion", "Confusion matrix (physics)", confusion_table(scores["physics"]["confusion"])),
        section("confusion-hybrid", "Confusion matrix (hybrid)",
                confusion_table(scores["hybrid"]["confusion"])),
        section("learned", "Learned residuals", para(_learned_note(results["learned"]))),
    ])  # fmt: skip
    return page("Fault benchmark", body)


def render_live(results: Mapping[str, Any]) -> str:
    """The live benchmark's page: the twin's scores beside the offline diagnosis's on the same
    records, and how the records were served."""
    scores = {"offline (diagnose)": results["offline"]["scores"],
              "live twin": results["twin"]["scores"]}  # fmt: skip
    lv = results["live"]
    wall = float(lv["wall_s"])
    served = (
        f"{results['machine_hours_served']:.1f} machine-hours served over MQTT on "
        f"{lv['machines']} machines at once, {lv['speed']:g}x real time each, in "
        f"{int(wall // 60)} min {wall % 60:.0f} s wall; {lv['received']} of {lv['published']} "
        f"samples received, {lv['dropped']} dropped; each machine learned "
        f"{lv.get('learn_s', lv['prelude_s']):g} s of its own healthy running first (of a "
        f"{lv['prelude_s']:g}-s healthy prelude), on top of the detector fitted on "
        f"{results['prior']['fitted_on']} tuning records"
    )
    events = ", ".join(f"{k}: {v}" for k, v in sorted(results["events"].items()))
    body = join([
        tag("h1", "Fault benchmark, live"),
        para(f"plan {results['plan']}, seed {results['seed']}: {served}.", cls="sub"),
        section("scores", "The twin beside the offline diagnosis",
                table([HEAD], score_rows(scores), id="scores"),
                para("The same records: the offline row pushes each record through the "
                     "diagnosis at once ('drafttwin diagnose'); the live row is what the twin "
                     "stored while the records were served as live machines. False alarms count "
                     "the watched healthy running (after each run's reference window); the "
                     "learning preludes are not watched.", cls="note")),
        _plant_section(results.get("plant")),
        section("confusion", "Confusion matrix (live twin)",
                confusion_table(results["twin"]["scores"]["confusion"])),
        section("events", "The twin's events", para(events)),
    ])  # fmt: skip
    return page("Fault benchmark, live", body)


def _plant_section(plant: Mapping[str, Any] | None) -> Any:
    """The shorter run against 'plant serve' (when it ran)."""
    if not plant:
        return ""
    scores = {"recorded, offline": plant["offline"]["scores"],
              "served, live twin": plant["twin"]["scores"]}  # fmt: skip
    faults = "; ".join(f"{c['name']} (seed {c['machine_seed']}): {c['fault']}"
                       for c in plant["cases"])  # fmt: skip
    return section(
        "plant",
        "The live plant itself",
        table([HEAD], score_rows(scores), id="plant-scores"),
        para(
            f"{plant['machines']} machines served by 'plant serve' over MQTT for "
            f"{plant['duration_s'] / 60:.0f} min at the wall clock, each learnt "
            f"first, a fault at a random time: {faults}. Beside them: the same "
            f"machines and faults recorded by the emulator and diagnosed offline "
            f"with the prior's thresholds. {plant['received']} samples received, "
            f"{plant['dropped']} dropped.",
            cls="note",
        ),
    )
