"""The EMPS benchmark report: text table, figure and a self-contained HTML page.

:func:`write_outputs` writes, atomically, into the output folder: ``emps_report.html`` (the
tables and a PNG figure embedded as base64), ``emps_results.json`` (everything
:func:`drafttwin.studies.emps.run.run_benchmark` measured) and ``emps_predictions.csv``
(time, measured ``qm`` and each model's seed-0 test prediction, m).
"""

from __future__ import annotations

import base64
import html
import io
import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from drafttwin._io import atomic_path, write_text_atomic  # noqa: E402
from drafttwin._json import dumps_strict  # noqa: E402
from drafttwin.report.figures import COLORS  # noqa: E402
from drafttwin.studies.emps.plan import PREDICTION_START, PUBLISHED, variant_name  # noqa: E402
from drafttwin.studies.emps.run import EmpsResult  # noqa: E402

LABELS = {
    "mechanistic": "physics only",
    "persistence": "persistence (hold)",
    "gru": "GRU (black box)",
    "lstm": "LSTM (black box)",
    "parallel": "parallel hybrid",
    "md-s-l": "MD-S-L",
}


def label(name: str) -> str:
    """Display name of a model or a :func:`~drafttwin.studies.emps.plan.variant_name`:
    ``parallel_refitted`` is "parallel hybrid (refitted physics)"."""
    model, _, physics = name.partition("_")
    if not physics:
        return LABELS.get(model, model)
    if model == "mechanistic":
        return f"physics only ({physics})"
    return f"{LABELS.get(model, model)} ({physics} physics)"


HEADER = ("model", "task", "test RMSE mm (mean ± std)", "min–max", "runs", "fit %",
          "published mm")  # fmt: skip


def _num(x: float, digits: int = 2) -> str:
    if x is None or not math.isfinite(x):
        return "n/a"
    if abs(x) < 1:
        digits += 1  # one-step prediction errors are hundredths of a mm
    return f"{x:.{digits}f}" if abs(x) < 1e4 else f"{x:.3g}"


def table_rows(results: dict[str, Any]) -> list[tuple[str, ...]]:
    """The benchmark table as text cells (see :data:`HEADER`)."""
    rows: list[tuple[str, ...]] = []
    for r in results["rows"]:
        spread = f"± {_num(r['rmse_mm_std'])}" if r["runs"] > 1 else ""
        pub = r.get("published_rmse_mm")
        rows.append((
            label(variant_name(r["model"], r.get("physics"))), r["task"],
            f"{_num(r['rmse_mm_mean'])} {spread}".strip(),
            f"{_num(r['rmse_mm_min'])}–{_num(r['rmse_mm_max'])}" if r["runs"] > 1 else "",
            str(r["runs"]), _num(r["fit_pct_mean"], 1), "" if pub is None else _num(pub, 2),
        ))  # fmt: skip
    return rows


def beyond(result: EmpsResult, span_mm: tuple[float, float]) -> list[str]:
    """The free runs drawn in the position panel that leave its axis (``span_mm``): the
    panel clipped a GRU's 616 mm without a word, where the error panels say so."""
    return sorted(label(name) for (task, name), pred in result.traces.items()
                  if task == "simulation" and name != "persistence" and np.any(np.isfinite(pred))
                  and (np.nanmin(pred) * 1e3 < span_mm[0] or np.nanmax(pred) * 1e3 > span_mm[1]))  # fmt: skip


def figure_png(result: EmpsResult) -> bytes:
    """Measured vs predicted test position (simulation), and the errors of both tasks."""
    t, y = result.test_time_s, result.test_qm_m
    fig, axes = plt.subplots(3, 1, figsize=(11, 10), sharex=True)
    axes[0].plot(t, y * 1e3, color="#222222", lw=1.6, label="measured qm")
    span = (np.nanmin(y) * 1e3 - 30, np.nanmax(y) * 1e3 + 30)
    for (task, name), pred in sorted(result.traces.items()):
        color = COLORS.get(name)  # refitted variants: matplotlib's next colour
        if task == "simulation" and name != "persistence":
            axes[0].plot(t, pred * 1e3, lw=0.9, color=color, label=label(name))
        ax = axes[1] if task == "simulation" else axes[2]
        ax.plot(t, (pred - y) * 1e3, lw=0.8, color=color, label=label(name))
    axes[0].set_ylim(*span)
    axes[0].set_ylabel("position, mm")
    out = beyond(result, span)
    leaves = (
        f"; axis clipped to the measured range ±30 mm: {', '.join(out)} leave it" if out else ""
    )
    axes[0].set_title("EMPS test record (DATA_EMPS_PULSES): free-run simulation, seed 0" + leaves)
    axes[1].set_ylim(-40, 40)
    axes[1].set_ylabel("simulation error, mm")
    axes[1].set_title("simulation errors (axis clipped at ±40 mm; black boxes leave it)")
    axes[2].set_ylim(-0.5, 0.5)
    axes[2].set_ylabel("prediction error, mm")
    axes[2].set_title("one-step prediction errors (axis clipped at ±0.5 mm)")
    axes[2].set_xlabel("time, s")
    for ax in axes:
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="upper left", fontsize=8, ncol=3)
        else:  # a task left out by --tasks: say so rather than draw an empty legend
            ax.text(0.5, 0.5, "not run (--tasks)", ha="center", va="center",
                    transform=ax.transAxes, color="#666666")  # fmt: skip
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def _html_table(results: dict[str, Any]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in HEADER)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells) + "</tr>"
        for cells in table_rows(results)
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def refit_line(results: dict[str, Any]) -> str:
    """One line on the refitted physics (empty without one)."""
    fit = results.get("physics_refit")
    if not fit:
        return ""
    p = fit["parameters"]
    return (
        f"refitted physics (output error on the training record, "
        f"{fit['nfev'] + 4 * fit.get('njev', 0)} simulations, {fit['fit_s']:.0f} s): M {p['mass_kg']:.3f} kg, Fv {p['viscous_ns_per_m']:.3f} "
        f"N s/m, Fc {p['coulomb_n']:.3f} N, offset {p['offset_n']:.4f} N; training-record "
        f"RMSE {fit['rmse_mm']:.3f} mm (published parameters {fit['rmse_mm_initial']:.3f} mm)"
    )


def _refit_html(results: dict[str, Any]) -> str:
    line = refit_line(results)
    return f"<p>{html.escape(line[0].upper() + line[1:])}.</p>" if line else ""


def report_html(result: EmpsResult) -> str:
    """The self-contained report page."""
    res = result.results
    png = base64.b64encode(figure_png(result)).decode("ascii")
    sources = "".join(
        f"<li><b>{html.escape(LABELS[k])}</b> {v['rmse_mm']} mm: {html.escape(v['source'])}</li>"
        for k, v in PUBLISHED.items()
    )
    proto = res["protocol"]
    partial = (
        f"<p class='warn'>Only the first {proto['max_samples']} samples of each record were "
        "used: a smoke test, not the official protocol.</p>"
        if proto.get("max_samples")
        else ""
    ) + (
        f"<p class='warn'>Every network trained {res['epochs_override']} epoch(s) (--epochs), "
        f"not the {html.escape(res['profile'])} profile's: not the benchmark's figures.</p>"
        if res.get("epochs_override")
        else ""
    )
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>drafttwin EMPS benchmark</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}}
table{{border-collapse:collapse}}td,th{{border:1px solid #bbb;padding:4px 8px;text-align:right}}
td:first-child,th:first-child{{text-align:left}}.warn{{color:#a00}}</style></head><body>
<h1>EMPS benchmark (real measurements)</h1>
<p>Train {html.escape(proto["train"])}, test {html.escape(proto["test"])}; input
{html.escape(proto["input"])}, output {html.escape(proto["output"])}. Simulation: free run
using only the first {proto["init_samples"]} measured test samples, RMSE over the rest
(the official metric). Prediction: one step ahead from the measured history (drafttwin's
protocol), scored from row {PREDICTION_START}; not
comparable with the simulation-mode literature. Profile <b>{html.escape(res["profile"])}</b>,
seeds {", ".join(str(s) for s in res["seeds"])}, drafttwin {html.escape(res["drafttwin_version"])},
wall time {res["wall_s"]:.0f} s.</p>{partial}
{_html_table(res)}{_refit_html(res)}
<h2>Published numbers (simulation task)</h2><ul>{sources}</ul>
<h2>Measured vs predicted position</h2>
<img alt="EMPS test record: measured vs predicted" src="data:image/png;base64,{png}"
 style="max-width:100%">
<p>Method, model definitions in simulation mode and findings: docs/emps.md.</p>
</body></html>
"""


def write_outputs(result: EmpsResult, out_dir: str | Path) -> list[Path]:
    """Write the report, the results JSON and the predictions CSV; returns the paths."""
    out = Path(out_dir)
    paths = [out / "emps_report.html", out / "emps_results.json", out / "emps_predictions.csv"]
    write_text_atomic(paths[0], report_html(result))
    write_text_atomic(paths[1], dumps_strict(result.results) + "\n")
    frame = pd.DataFrame({"time": result.test_time_s, "qm_measured": result.test_qm_m})
    for (task, name), pred in sorted(result.traces.items()):
        frame[f"{name}_{task}"] = pred
    with atomic_path(paths[2]) as tmp:
        frame.to_csv(tmp, index=False, float_format="%.9g")
    return paths
