"""Section 1 of the report: title, the data (plant emulator), what was run and where the time went."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from drafttwin._constants import ROLLERS
from drafttwin.evaluation.metrics import DEFAULT_REL_FLOOR
from drafttwin.report.fmt import DASH, is_num, seconds
from drafttwin.report.html import (
    Cell,
    Raw,
    bullets,
    join,
    kv_table,
    para,
    section,
    table,
    tag,
    value_text,
)
from drafttwin.report.tables import metric_unit

if TYPE_CHECKING:
    from drafttwin.report.html import Row

TITLE = "drafttwin study: predicting the bottom-roller speeds of an FA320A drafting section"

PLANT_ADDS = (
    "true parameters that differ from the nominal preset (friction coefficient ±15 %, belt "
    "creep ±30 %, mesh, shaft and chain stiffnesses, motor breakdown torque, bearing friction); "
    "gear backlash and gear eccentricity; the drafting force of the sliver with a fast and a slow "
    "fluctuation; roller run-out; thermal drift of the motor slip; jitter of the VFD supply "
    "frequency; encoder pulse counting (0.6 rpm step at 100 Hz) with window jitter; dropped "
    "samples, bursts of them and spikes"
)
PLANT_LEAVES_OUT = (
    "top-roller and fibre slip (they change the sliver speed, not the bottom-roller speed), wear, "
    "faults, and any dynamics outside the torsional model's structure: the plant is built from "
    "the same component models as our mechanistic model, so the structural error of a real "
    "machine is only partly present. Disturbance magnitudes come from the literature or are "
    "assumptions, not measurements on an FA320A (docs/plant.md)"
)
METRIC_RULES = (
    "Relative error = 100·|y − ŷ|/|y| in % (max and mean), over the samples with |y| at least "
    "{floor:.0%} of the roller's scale (the 99th percentile of |y|; lower samples, start-up and "
    "stops, "
    "are excluded and counted; a signal that crosses zero gets none); prediction accuracy = "
    "100 − mean relative error (the paper's Table 3 quantity). RMSE in {unit}; NRMSE = RMSE / "
    "std of the measured test speed; skill = 1 − RMSE / RMSE of persistence (ŷ(t) = y(t−1)): 0 "
    "means no better than repeating the last measurement. Where the true speed is known: "
    "sensor error = RMSE of measured vs true speed (the encoders' own error); RMSE vs true / "
    "sensor error below 1 means the model estimates the true speed better than the encoder "
    "measures it; floor = the lowest RMSE any one-step predictor of the measured speed can "
    "reach (an oracle that knows the true speed and every earlier measurement: consecutive "
    "windows share a boundary's counting error with opposite signs, so part of it can be "
    "foreseen and the floor lies near 1/√2 of the sensor error). Each prediction uses "
    "measurements up to t−1 only; scalers and all fitted statistics come from the training part."
)
"""The scoring rules; ``{unit}`` is the metrics' unit, ``{floor}`` the relative-error floor."""


def metric_rules(unit: str) -> str:
    """The scoring rules for metrics in ``unit`` (``""``: undeclared)."""
    return METRIC_RULES.format(unit=unit or "the signal's unit", floor=DEFAULT_REL_FLOOR)


def ours_label(results: Mapping[str, Any]) -> str:
    """The heading of our column: the emulator's data, or the file the study read."""
    return "ours (plant emulator)" if is_plant(results) else "ours (the measurements read)"


def is_plant(results: Mapping[str, Any]) -> bool:
    """Whether the data come from the plant emulator: a plant summary, or a known true speed
    (a finite sensor error), which only the emulator provides."""
    if results["data"].get("plant_summary"):
        return True
    metrics = results["comparison"]["metrics"].values()
    return any(is_num(m.get("sensor_rmse")) for per in metrics for m in per.values())


def _hyper_items(prof: Mapping[str, Any]) -> dict[str, Any]:
    names = {"model_profile": "model hyperparameters (profile)",
             "data_hyper": "data-driven model overrides",
             "residual_hyper": "residual model overrides"}  # fmt: skip
    return {title: value_text(prof[k]) for k, title in names.items() if k in prof}


def _run_items(results: Mapping[str, Any]) -> dict[str, Any]:
    data, prof = results["data"], results["profile"]
    abl = results.get("ablation", {})
    machine = results.get("machine", {})
    mech = results.get("mechanistic", {})
    mech_text = str(mech.get("source", DASH))
    if is_num(mech.get("wall_s")):
        mech_text += f" (data prepared and simulated in {seconds(mech['wall_s'])})"
    return {
        "profile": prof.get("name"),
        "profile settings": value_text(prof.get("settings", {})),
        **_hyper_items(prof),
        "data set": f"{data.get('name') or 'default'} (hash {data.get('hash', DASH)})",
        "rows": f"{data.get('rows')} at {value_text(data.get('rate_hz'))} Hz "
        f"({seconds(data.get('duration_s'))})",
        "split (chronological)": f"training {data.get('train_rows')} rows "
        f"({value_text(data.get('train_fraction'))}), test {data.get('test_rows')} rows",
        "mechanistic model": mech_text,
        "ablation seeds": value_text(abl.get("seeds", [])),
        "repeated tests share one data-driven model": value_text(abl.get("shared_data_model")),
        "drafttwin / Python / torch": f"{results.get('drafttwin_version', DASH)} / "
        f"{machine.get('python', DASH)} / {machine.get('torch', DASH)}",
        "machine": f"{machine.get('cpu', DASH)}, {machine.get('logical_cores', DASH)} logical "
        f"cores, device {machine.get('device', DASH)}",
        "created (UTC)": results.get("created_utc", DASH),
    }


def data_notice(results: Mapping[str, Any]) -> Raw:
    """Where the data come from, in two lines; the plant's details folded away."""
    data = results["data"]
    if not is_plant(results):
        name = data.get("name") or "measured data"
        return tag("div", tag("strong", f"Data: {name} (measurements read from a file)."),
                   cls="banner")  # fmt: skip
    summary = [str(s) for s in data.get("plant_summary") or []]
    adds = join([tag("strong", "What the plant adds"), " to the nominal model: ", PLANT_ADDS, "."])
    details: list[Raw | str] = [
        tag("summary", "What the plant adds and what it leaves out"),
        bullets(summary) if summary else "",
        para(adds),
        para(join([tag("strong", "What it leaves out: "), PLANT_LEAVES_OUT, "."])),
    ]
    parts: list[Raw | str] = [
        tag("strong", "Data: plant emulator, not a real FA320A."),
        " No public FA320A roller-speed measurements exist: our numbers come from drafttwin's "
        "plant emulator, the paper's from a real FA320A. Compare trends, not absolute values.",
        tag("details", join(details)),
    ]
    return tag("div", join(parts), cls="banner")


def _roller_table(counts: Mapping[str, Any]) -> Raw:
    """Nested counts; a mapping keyed by the rollers becomes one row with four columns."""
    body: list[list[Cell | str]] = []

    def row(name: str, per_roller: Mapping[str, Any]) -> None:
        body.append([Cell(name, cls="name")] + [value_text(per_roller.get(r)) for r in ROLLERS])

    def walk(prefix: str, value: Any) -> None:
        if not (isinstance(value, Mapping) and value):
            body.append([Cell(prefix, cls="name"), Cell(value_text(value), colspan=len(ROLLERS))])
            return
        inner = [v for v in value.values() if isinstance(v, Mapping)]
        if set(value) <= set(ROLLERS) and not inner:
            row(prefix, value)
        elif set(value) <= set(ROLLERS) and len(inner) == len(value):
            for key in dict.fromkeys(k for v in inner for k in v):
                row(f"{prefix} · {key}", {r: v.get(key) for r, v in value.items()})
        else:
            for k, v in value.items():
                walk(f"{prefix} · {k}" if prefix else str(k), v)

    walk("", counts)
    head: list[Row] = [[Cell("item", header=True, cls="name"), *ROLLERS]]
    return table(head, body, id="preprocessing")


def _timing_tables(timings: Mapping[str, Any]) -> Raw:
    total = timings.get("total_s")
    stages = dict(timings.get("stages", {}))
    if is_num(total):
        rest = total - sum(v for v in stages.values() if is_num(v))
        if rest > 0.005 * total:
            stages["other (bookkeeping, report)"] = rest
    body: list[Row] = []
    for name, s in stages.items():
        share = s / total if is_num(total) and total > 0 and is_num(s) else float("nan")
        bar = (
            Raw(f'<span class="bar" style="width:{200 * share:.0f}px"></span>')
            if is_num(share)
            else ""
        )
        body.append(
            [
                Cell(name, cls="name"),
                seconds(s),
                f"{100 * share:.1f} %" if is_num(share) else DASH,
                bar,
            ]
        )
    head: list[Row] = [
        [Cell("stage", header=True, cls="name"), "wall time", "share", Cell("", header=True)]
    ]
    parts: list[Raw | str] = [
        para(
            f"Total wall time {seconds(total)}, up to writing this page (the report's own "
            "writing is in results.json; the command's time, reading the data included, is "
            "what reproduce prints)."
        ),  # fmt: skip
        table(head, body, id="timings"),
    ]
    fits = [f for f in timings.get("fits", []) if is_num(f.get("wall_s"))]
    if fits:
        slow = sorted(fits, key=lambda f: -f["wall_s"])[:8]
        fit_total = sum(f["wall_s"] for f in fits)
        parts.append(
            para(
                f"{len(fits)} model fits took {seconds(fit_total)} in all (summed; "
                "they may have run in parallel). The slowest:"
            )
        )
        parts.append(
            table(
                [[Cell("fit", header=True, cls="name"), "wall time"]],
                [[Cell(f["task"], cls="name"), seconds(f["wall_s"])] for f in slow],
                id="slowest-fits",
            )
        )
    return join(parts)


def toc(entries: list[tuple[str, str]]) -> Raw:
    """The table of contents: one bar that stays at the top of the window."""
    items = [tag("li", tag("a", title, href=f"#{sid}")) for sid, title in entries]
    return tag("nav", join([tag("strong", "Contents"), tag("ol", join(items))]), cls="toc")


def header(results: Mapping[str, Any]) -> Raw:
    """Title and the run's one-line identity."""
    prof = results["profile"].get("name", DASH)
    sub = (
        f"drafttwin {results.get('drafttwin_version', DASH)} · profile {prof} · "
        f"created {results.get('created_utc', DASH)} (UTC)"
    )
    return tag("header", join([tag("h1", TITLE), para(sub, cls="sub")]))


def run_section(results: Mapping[str, Any]) -> Raw:
    """Section 1: what was run, scoring rules, preprocessing, timings."""
    prof = results["profile"]
    parts: list[Raw | str] = [tag("h3", "What was run"), kv_table(_run_items(results), id="run")]
    if prof.get("notes"):
        parts += [para(f"Notes of the {prof.get('name')} profile:"), bullets(prof["notes"])]
    parts += [
        tag("h3", "Scoring rules"),
        para(results["data"].get("scoring", DASH)),
        para(metric_rules(metric_unit(results)), cls="note"),
    ]
    if results["data"].get("preprocessing"):
        parts += [
            tag("h3", "Preprocessing (counts)"),
            _roller_table(results["data"]["preprocessing"]),
        ]
    parts += [tag("h3", "Where the time went"), _timing_tables(results.get("timings", {}))]
    return section("run", "1. What was run", *parts)
