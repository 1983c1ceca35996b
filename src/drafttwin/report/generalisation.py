"""The generalisation benchmark's report: text tables, the learning-curve and extrapolation
figures and a self-contained HTML page.

:func:`write_outputs` writes, atomically, ``generalisation_report.html`` (tables and PNG
figures embedded as base64) and ``generalisation_results.json`` (everything
:func:`drafttwin.studies.generalisation.run_benchmark` measured) into the output folder.
"""

from __future__ import annotations

import base64
import html
import io
import math
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.ticker import FixedLocator, FuncFormatter, NullLocator  # noqa: E402

from drafttwin._constants import ROLLERS  # noqa: E402
from drafttwin._io import write_text_atomic  # noqa: E402
from drafttwin._json import dumps_strict  # noqa: E402
from drafttwin.report import figures  # noqa: E402
from drafttwin.report.figures import COLORS, log_axis_plain  # noqa: E402
from drafttwin.report.fmt import sig_fixed  # noqa: E402
from drafttwin.report.html import Cell, Raw, bullets, figure, join, para, section, table, tag  # noqa: E402
from drafttwin.studies.generalisation.records import (  # noqa: E402
    MACHINE_SEED,
    SCENARIOS,
    TEST_RECORDS,
)

if TYPE_CHECKING:
    from drafttwin.report.html import Row

MODELS = ("mechanistic", "mechanistic (calibrated)", "persistence", "gru", "parallel", "md-s-l")
LABELS = {
    "mechanistic": "physics",
    "mechanistic (calibrated)": "physics, calibrated",
    "persistence": "persistence",
    "gru": "GRU",
    "parallel": "parallel hybrid",
    "md-s-l": "MD-S-L",
}
TASKS = ("prediction", "simulation")


def _color(model: str) -> str | None:
    return "#e377c2" if model == "mechanistic (calibrated)" else COLORS.get(model)


def _num(x: Any, digits: int = 3) -> str:
    if x is None or not isinstance(x, int | float) or not math.isfinite(x):
        return "n/a"
    return f"{x:.{digits}g}" if abs(x) < 1e4 else f"{x:.3g}"


def _cell(stats: Mapping[str, Any] | None) -> str:
    if not stats or stats.get("mean") is None:
        return ""
    if stats.get("n", 1) > 1:
        return f"{_num(stats['mean'])} ± {_num(stats['std'], 2)}"
    return _num(stats["mean"])


def extrapolation_rows(doc: Mapping[str, Any], task: str) -> tuple[list[str], list[list[str]]]:
    """The extrapolation table of ``task``: one row per scenario and roller, RMSE (rpm, mean
    ± std over seeds) per model at the full training length."""
    table = {(r["scenario"], r["model"], r["channel"]): r["rmse"] for r in doc["extrapolation"]
             if r["task"] == task}  # fmt: skip
    models = [m for m in MODELS if any(k[1] == m for k in table)]
    head = ["scenario", "roller", *(LABELS[m] for m in models)]
    rows = []
    for scenario in SCENARIOS:
        for channel in ROLLERS:
            if any((scenario, m, channel) in table for m in models):
                rows.append([scenario, channel,
                             *(_cell(table.get((scenario, m, channel))) for m in models)])  # fmt: skip
    return head, rows


def ratio_rows(doc: Mapping[str, Any]) -> tuple[list[str], list[list[str]]]:
    """Hybrid RMSE / GRU RMSE (same seed) at the full training length, mean ± std."""
    train_s = max(doc["config"]["train_lengths_s"])
    table = {(r["scenario"], r["task"], r["model"], r["channel"]): r["ratio_to_gru"]
             for r in doc["hybrid_vs_gru"] if r["train_s"] == train_s}  # fmt: skip
    head = ["scenario", "task", "roller", "parallel / GRU", "MD-S-L / GRU"]
    rows = []
    for scenario in SCENARIOS:
        for task in TASKS:
            for channel in ROLLERS:
                cells = [
                    _cell(table.get((scenario, task, m, channel))) for m in ("parallel", "md-s-l")
                ]
                if any(cells):
                    rows.append([scenario, task, channel, *cells])
    return head, rows


def learning_rows(doc: Mapping[str, Any]) -> tuple[list[str], list[list[str]]]:
    """The learning curves as numbers: RMSE (mean ± std over seeds) per training length."""
    lengths = sorted({r["train_s"] for r in doc["learning_curves"]})
    head = ["task", "model", "roller", *(f"{n:g} s" for n in lengths)]
    table = {(r["task"], r["model"], r["channel"], r["train_s"]): r["rmse"]
             for r in doc["learning_curves"]}  # fmt: skip
    rows = []
    for task in TASKS:
        for model in MODELS:
            for channel in ROLLERS:
                cells = [_cell(table.get((task, model, channel, n))) for n in lengths]
                if any(cells):
                    rows.append([task, LABELS[model], channel, *cells])
    return head, rows


def learning_png(doc: Mapping[str, Any]) -> bytes:
    """RMSE against training length per task and roller (mean, bars: min-max over seeds);
    the physics and persistence, which do not learn, as horizontal lines."""
    curves = doc["learning_curves"]
    fig, axes = plt.subplots(2, 4, figsize=(15, 7), squeeze=False)
    for i, task in enumerate(TASKS):
        for j, channel in enumerate(ROLLERS):
            ax = axes[i][j]
            mine = [r for r in curves if r["task"] == task and r["channel"] == channel
                    and r["rmse"]["mean"] is not None]  # fmt: skip
            for model in MODELS:
                pts = sorted((r["train_s"], r["rmse"]) for r in mine if r["model"] == model)
                if not pts:
                    continue
                color = _color(model)
                if model in ("mechanistic", "persistence", "mechanistic (calibrated)"):
                    ax.axhline(pts[-1][1]["mean"], color=color, ls="--", lw=1, label=LABELS[model])
                    continue
                x = [p[0] for p in pts]
                y = [p[1]["mean"] for p in pts]
                lo = [p[1]["mean"] - p[1]["min"] for p in pts]
                hi = [p[1]["max"] - p[1]["mean"] for p in pts]
                ax.errorbar(x, y, yerr=[lo, hi], marker="o", capsize=3, color=color,
                            label=LABELS[model])  # fmt: skip
            ax.set_xscale("log")
            ax.set_yscale("log")
            log_axis_plain(ax.yaxis)
            lengths = sorted({r["train_s"] for r in mine})
            if lengths:  # ticks at the lengths trained on (a log locator put 3 and 5 by 3 and 6)
                ax.xaxis.set_major_locator(FixedLocator(lengths))
                ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
                ax.xaxis.set_minor_locator(NullLocator())
            ax.set_title(f"{channel} roller, {task}", fontsize=10)
            ax.grid(alpha=0.3, which="both")
            if i == 1:
                ax.set_xlabel("training length, s")
            if j == 0:
                ax.set_ylabel("test RMSE, rpm")
    axes[0][0].legend(fontsize=8)
    return _png(fig)


def extrapolation_png(doc: Mapping[str, Any]) -> bytes:
    """Free-run RMSE per scenario (mean over rollers of each seed's mean), per model."""
    rows = [r for r in doc["extrapolation"] if r["task"] == "simulation"]
    fig, ax = plt.subplots(figsize=(14, 4.5))
    models = [m for m in MODELS if any(r["model"] == m for r in rows)]
    width = 0.8 / max(1, len(models))
    for k, model in enumerate(models):
        xs, ys = [], []
        for i, scenario in enumerate(SCENARIOS):
            vals = [r["rmse"]["mean"] for r in rows if r["model"] == model
                    and r["scenario"] == scenario and r["rmse"]["mean"] is not None]  # fmt: skip
            if vals:
                xs.append(i + (k - len(models) / 2 + 0.5) * width)
                ys.append(sum(vals) / len(vals))
        ax.bar(xs, ys, width, color=_color(model), label=LABELS[model])
    ax.set_xticks(range(len(SCENARIOS)), SCENARIOS, rotation=20)
    ax.set_yscale("log")
    ax.set_ylabel("free-run RMSE, rpm (mean over rollers)")
    ax.grid(alpha=0.3, axis="y", which="both")
    # above the axes: inside, it covered the bars of a scenario
    ax.legend(fontsize=8, ncol=len(models), loc="lower center", bbox_to_anchor=(0.5, 1.0),
              frameon=False)  # fmt: skip
    return _png(fig)


def _png(fig: Any) -> bytes:
    buf = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format="png", dpi=80)
    plt.close(fig)
    return buf.getvalue()


def html_table(head: list[str], rows: list[list[str]]) -> str:
    th = "".join(f"<th>{html.escape(h)}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>"
                   for r in rows)  # fmt: skip
    return f"<table><thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>"


def _img(png: bytes, alt: str) -> str:
    data = base64.b64encode(png).decode("ascii")
    return (
        f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{data}" style="max-width:100%">'
    )


def structure_rows(doc: Mapping[str, Any]) -> tuple[list[str], list[list[str]]]:
    head = [
        "model",
        "task",
        "chosen",
        "validation scores (RMSE / physics RMSE, mean over rollers and the validation records)",
    ]
    rows = []
    for r in doc["structure_choice"]:
        scores = "; ".join(f"{structure_name(s)} {_num(s['score'])}" for s in r["scores"])
        rows.append([r["model"], r["task"], structure_name(r), scores])
    return head, rows


def structure_name(choice: Mapping[str, Any]) -> str:
    """``relative + fade``, ``absolute + strict fade, no skip``, ``relative`` ..."""
    fade = choice.get("fade")
    suffix = " + strict fade" if fade == "strict" else " + fade" if fade else ""
    skip = ", no skip" if choice.get("skip") is False else ""
    return f"{choice['structure']}{suffix}{skip}"


def check_lines(doc: Mapping[str, Any]) -> list[str]:
    """The issue's test, one line per scenario."""
    out = []
    for c in doc["checks"]:
        failed = [ch for ch, v in c["channels"].items()
                  if not (v["physics_beats_gru"] and v["a_hybrid_beats_gru"])]  # fmt: skip
        verdict = "holds" if c["holds"] else f"does not hold on {', '.join(failed)}"
        out.append(f"{c['scenario']}, free run: physics and a hybrid below the GRU on every "
                   f"roller: {verdict}")  # fmt: skip
    return out


def floor_rows(doc: Mapping[str, Any]) -> tuple[list[str], list[list[str]]]:
    head = ["roller", "floor, rpm", "best one-step RMSE, rpm", "best model", "below the floor?"]
    rows = [[f["channel"], _num(f["floor"]), _num(f["best_rmse"]), str(f["best_model"]),
             _below_floor(f["best_rmse"], f["floor"], f.get("sensor_error_lag1"))]
            for f in doc["floors"]]  # fmt: skip
    return head, rows


def _below_floor(best_rmse: float | None, floor: float | None, lag1: float | None) -> str:
    """The floor's verdict; the oracle gives no floor (None in the JSON) where the channel's
    encoder errors lack the counting premise's lag-one autocorrelation (-1/2), or without a
    run."""
    if floor is None:
        return "no floor" if lag1 is None else (
            f"no floor (sensor errors' lag-1 autocorrelation {lag1:.2f}, not a counting "
            "encoder's -0.5)")  # fmt: skip
    if best_rmse is None:
        return "no run"
    return "YES (the floor is wrong)" if best_rmse < floor else "no"


def report_html(doc: Mapping[str, Any]) -> str:
    """The self-contained report page."""
    cfg = doc["config"]
    records = "".join(f"<li><b>{html.escape(k)}</b>: {html.escape(v['what'])}, "
                      f"{v['duration_s']:.0f} s</li>" for k, v in doc["records"].items())  # fmt: skip
    parts = [
        f"<h1>Where does the physics pay? Generalisation benchmark ({html.escape(cfg['name'])})</h1>",
        "<p>Every learned model is trained on steady running of one machine at the FA320A "
        "preset's set-point and tested on plant records its training never saw. RMSE in rpm "
        f"against the measured speeds, scored from row {2 * cfg['window']} of each record; "
        f"{cfg['seeds']} seed(s); network {cfg['layers']} x {cfg['hidden']}, window "
        f"{cfg['window']}, at most {cfg['epochs']} epochs. drafttwin "
        f"{html.escape(doc['drafttwin_version'])}, {doc['timings']['total_s']:.0f} s.</p>",
        f"<h2>Records</h2><ul>{records}</ul>",
        "<h2>Hybrid structure chosen on the validation records</h2>",
        html_table(*structure_rows(doc)),
        "<h2>Checks</h2><ul>"
        + "".join(f"<li>{html.escape(s)}</li>" for s in check_lines(doc))
        + "</ul>",
        "<h2>Free-run RMSE per scenario</h2>",
        _img(extrapolation_png(doc), "extrapolation"),
    ]
    for task in TASKS:
        parts += [
            f"<h2>Extrapolation table: {task}</h2>",
            html_table(*extrapolation_rows(doc, task)),
        ]
    parts += ["<h2>Hybrid / GRU (same seed)</h2>", html_table(*ratio_rows(doc)),
              "<h2>Learning curves (little-data test record)</h2>",
              _img(learning_png(doc), "learning curves"), html_table(*learning_rows(doc)),
              "<h2>One-step floor</h2><p>Oracle floor: the true speed and every earlier "
              "measurement known, the counting encoder's error predicted with its exact best "
              "linear weights (evaluation.limits); no predictor of the measured value can do "
              "better. The best one-step RMSE of any run on the same record beside it. No "
              "floor where the sensor errors lack a counting encoder's lag-1 autocorrelation "
              "(-0.5).</p>",
              html_table(*floor_rows(doc)),
              "<p>Method and findings: docs/generalisation.md.</p>"]  # fmt: skip
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>drafttwin generalisation benchmark</title>
<style>body{{font-family:sans-serif;max-width:1200px;margin:2em auto;color:#222}}
table{{border-collapse:collapse;margin-bottom:1em}}td,th{{border:1px solid #bbb;padding:3px 7px;
text-align:right}}td:first-child,th:first-child{{text-align:left}}</style></head><body>
{"".join(parts)}
</body></html>
"""


def write_outputs(doc: Mapping[str, Any], out_dir: str | Path) -> list[Path]:
    """Write the report and the results JSON; returns the paths."""
    out = Path(out_dir)
    paths = [out / "generalisation_report.html", out / "generalisation_results.json"]
    write_text_atomic(paths[0], report_html(doc))
    write_text_atomic(paths[1], dumps_strict(doc) + "\n")
    return paths


def scenario_means(doc: Mapping[str, Any], task: str) -> tuple[list[str], list[list[str]]]:
    """Per scenario, each model's RMSE averaged over the rollers (seed means), one task."""
    groups: dict[tuple[str, str], list[float]] = {}
    for r in doc["extrapolation"]:
        if r["task"] == task and r["rmse"]["mean"] is not None:
            groups.setdefault((r["scenario"], r["model"]), []).append(r["rmse"]["mean"])
    models = [m for m in MODELS if any(k[1] == m for k in groups)]
    rows = [[s, *(sig_fixed(sum(v) / len(v)) if (v := groups.get((s, m))) else ""
                  for m in models)]
            for s in SCENARIOS if any((s, m) in groups for m in models)]  # fmt: skip
    return ["scenario", *(LABELS[m] for m in models)], rows


def study_summary(doc: Mapping[str, Any]) -> dict[str, Any]:
    """What the study's results.json keeps of a benchmark run (the summaries, not the rows)."""
    keys = ("config", "extrapolation", "checks", "structure_choice", "floors", "timings")
    return {k: doc[k] for k in keys}


STEADY_SPEED = {
    name: round(100.0 * (spec.speed_scale - 1.0), 6)
    for name, spec in TEST_RECORDS.items()
    if spec.plant_scenario == "steady" and not spec.draft_gears
    and spec.machine_seed == MACHINE_SEED
}  # fmt: skip
"""Speed change from the training point (%) of the records that differ from it in speed only
(steady running of the training machine; ``little-data`` is at the training set-point)."""


def speed_curves(doc: Mapping[str, Any], task: str) -> dict[str, list[tuple[float, float]]]:
    """Per model (display name): (speed change %, RMSE averaged over the rollers) on the
    records of :data:`STEADY_SPEED`, the same numbers as :func:`scenario_means`."""
    groups: dict[tuple[str, str], list[float]] = {}
    for r in doc["extrapolation"]:
        if r["task"] == task and r["scenario"] in STEADY_SPEED and r["rmse"]["mean"] is not None:
            groups.setdefault((r["model"], r["scenario"]), []).append(r["rmse"]["mean"])
    out: dict[str, list[tuple[float, float]]] = {}
    for model in MODELS:
        points = [(STEADY_SPEED[s], sum(v) / len(v)) for (m, s), v in groups.items() if m == model]
        if len(points) > 1:
            out[LABELS[model]] = sorted(points)
    return out


def speed_figure(doc: Mapping[str, Any]) -> Raw:
    """RMSE against the speed change from the training point, free run and one step ahead."""
    titles = {"simulation": "free-run simulation", "prediction": "one-step prediction"}
    curves = {titles[t]: c for t in TASKS if (c := speed_curves(doc, t))}
    if not curves:
        return Raw("")
    colors = {LABELS[m]: _color(m) for m in MODELS}
    caption = (
        "RMSE (rpm, mean over the four rollers, log scale) against the speed change from the "
        "training point: the training machine at steady running with its set-point scaled; "
        "0 %: the training set-point (another recording). The learned models were trained at "
        "0 % only."
    )
    hidden = _coinciding(curves)
    if hidden:
        caption += " " + hidden
    png = figures.speed_change(curves, colors, unit="rpm")
    return figure(png, "fig-speed-change", caption, "RMSE against speed change")


def _coinciding(curves: Mapping[str, Mapping[str, list[tuple[float, float]]]]) -> str:
    """A sentence naming the curves drawn under another with the same values (a hybrid that
    kept no correction is its physics: its line cannot be seen), or ``""``."""
    said = []
    for title, by_model in curves.items():
        names = list(by_model)
        for k, name in enumerate(names):
            # the one drawn last is seen; an earlier one with the same points lies under it
            over = next((o for o in reversed(names[k + 1 :])
                         if _same(by_model[o], by_model[name])), None)  # fmt: skip
            if over is not None:
                said.append(f"{name} under {over} ({title})")
    if not said:
        return ""
    return ("Lines with the same values lie under one another: " + "; ".join(said) +
            " (a hybrid that kept no correction predicts its physics).")  # fmt: skip


def _same(a: list[tuple[float, float]], b: list[tuple[float, float]]) -> bool:
    return len(a) == len(b) and all(xa == xb and math.isclose(ya, yb, rel_tol=1e-9)
                                    for (xa, ya), (xb, yb) in zip(a, b, strict=True))  # fmt: skip


def _study_table(head: list[str], rows: list[list[str]], wrap: int | None = None) -> Raw:
    """A benchmark table in the study page's style; column ``wrap`` wraps its text."""
    body: list[Row] = [
        [
            Cell(c, cls="wrap" if k == wrap else ("name" if k == 0 else None))
            for k, c in enumerate(r)
        ]
        for r in rows
    ]
    return table([[Cell(h, header=True) for h in head]], body)


def physics_pays_section(results: Mapping[str, Any]) -> str:
    """The study report's "Where does the physics pay?" section (empty without results)."""
    doc = results.get("generalisation")
    if not doc:
        return ""
    cfg = doc["config"]
    intro = join([
        "The generalisation benchmark's quick subset (", tag("code", "drafttwin benchmark "
        "generalisation --quick"), "): every learned model trained on "
        f"{max(cfg['train_lengths_s']):g} s of steady running of one plant machine at one "
        f"set-point (networks {cfg['layers']} × {cfg['hidden']}, {cfg['epochs']} epochs: a "
        "smoke-test budget, far below the study's), then tested where its training never went. "
        "The full benchmark's figures are in docs/generalisation.md.",
    ])  # fmt: skip
    unit = "RMSE (rpm), mean over the four rollers"
    return section(
        "generalisation",
        "Where does the physics pay?",
        para(intro),
        speed_figure(doc),
        tag("h3", f"Free-run simulation: {unit}"),
        _study_table(*scenario_means(doc, "simulation")),
        tag("h3", f"One-step prediction: {unit}"),
        _study_table(*scenario_means(doc, "prediction")),
        tag("h3", "Hybrid structure chosen on validation records"),
        _study_table(*structure_rows(doc), wrap=3),
        bullets(check_lines(doc)),
    ).html
