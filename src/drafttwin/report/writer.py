"""``write_report``: the study report (one self-contained HTML file) and its CSV tables;
``write_study``: all a study run writes."""

from __future__ import annotations

import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from drafttwin._constants import ROLLERS
from drafttwin._io import atomic_path, write_text_atomic
from drafttwin._json import dumps_strict
from drafttwin.report import figures, paper, tables
from drafttwin.report.agreement import label
from drafttwin.report.comparison import comparison_section, figures_section
from drafttwin.report.generalisation import physics_pays_section
from drafttwin.report.glance import glance_section, headline_png
from drafttwin.report.html import Raw, join, page, tag
from drafttwin.report.overview import TITLE, data_notice, header, is_plant, run_section, toc
from drafttwin.report.physics import calibration_section
from drafttwin.report.studies import ablation_section, agreement_section, grid_section

TOC = [
    ("glance", "At a glance"),
    ("run", "1 Run"),
    ("comparison", "2 Comparison"),
    ("predictions", "3 Predictions"),
    ("grid", "4 Grid search"),
    ("ablation", "5 Ablation"),
    ("calibration", "Calibrated physics"),
    ("agreement", "6 Agreement"),
    ("generalisation", "Where the physics pays"),
]
CSV_FLOAT = "%.10g"


def _matrix(predictions: pd.DataFrame, prefix: str) -> np.ndarray | None:
    """The (n, 4) block ``<prefix>_<roller>``, or None if any column is missing."""
    cols = [f"{prefix}_{r}" for r in ROLLERS]
    if not all(c in predictions.columns for c in cols):
        return None
    block: np.ndarray = predictions[cols].to_numpy(dtype=np.float64)
    return block


def zoom_window(time_s: np.ndarray, length_s: float = 2.0) -> tuple[float, float]:
    """A window of ``length_s`` (at most a quarter of the span) starting mid test part."""
    if time_s.size == 0:
        return 0.0, 0.0
    t0, t1 = float(time_s[0]), float(time_s[-1])
    length = min(length_s, (t1 - t0) / 4) if t1 > t0 else 0.0
    start = t0 + (t1 - t0) / 2
    return start, start + length


def _prediction_figures(results: Mapping[str, Any], predictions: pd.DataFrame) -> dict[str, bytes]:
    main, _ = tables.compared_models(results)
    time_s = predictions["time"].to_numpy(dtype=np.float64)
    measured = _matrix(predictions, "measured")
    if measured is None:
        raise ValueError("predictions lacks measured_<roller> columns")
    true = _matrix(predictions, "true")
    if true is not None and not np.isfinite(true).any():
        true = None
    preds = {m: p for m in main if (p := _matrix(predictions, m)) is not None}
    shown = {m: p for m, p in preds.items() if m != "persistence"}
    zoom = zoom_window(time_s)
    resid = {m: measured - p for m, p in preds.items()}
    rate = float(results["data"].get("rate_hz") or 1.0 / np.median(np.diff(time_s)))
    unit = tables.metric_unit(results)
    return {
        "predictions": figures.predictions(time_s, measured, shown, zoom, true=true, unit=unit),
        "residuals": figures.residuals(time_s, resid, rate, unit=unit),
    }


def _summary_figures(results: Mapping[str, Any]) -> dict[str, bytes]:
    main, extra = tables.compared_models(results)
    metrics = results["comparison"]["metrics"]

    def values(key: str) -> dict[str, list[float]]:
        return {m: [tables.as_float(metrics[m][r].get(key)) for r in ROLLERS] for m in main + extra}

    limits = {k: [tables.as_float(metrics[main[0]][r].get(k)) for r in ROLLERS]
              for k in ("rmse_floor", "sensor_rmse")}  # fmt: skip
    abl = results["ablation"]
    acc = {v: np.asarray(abl["accuracy"][v], dtype=float) for v in abl["variants"]}
    paper_means = {
        r: [
            paper.table3_mean(r, v) if v in paper.TABLE3_VARIANTS else float("nan")
            for v in abl["variants"]
        ]
        for r in ROLLERS
    }
    grid = {net: results["grid"][net] for net in ("lstm", "gru") if results["grid"].get(net)}
    return {
        "rmse": figures.rmse_overview(
            values("rmse"),
            values("rmse_vs_true"),
            limits["rmse_floor"],
            limits["sensor_rmse"],
            unit=tables.metric_unit(results),
        ),
        "grid": figures.grid_losses(grid),
        "ablation": figures.ablation_spread(acc, paper_means, {v: label(v) for v in acc}),
        "headline": headline_png(results),
    }


def _toc(results: Mapping[str, Any]) -> list[tuple[str, str]]:
    optional = ("calibration", "generalisation")
    return [t for t in TOC if t[0] not in optional or results.get(t[0])]


def render_html(results: Mapping[str, Any], predictions: pd.DataFrame) -> str:
    """The whole report page as a string."""
    figs = {**_summary_figures(results), **_prediction_figures(results, predictions)}
    main, _ = tables.compared_models(results)
    plotted = [m for m in main if m != "persistence" and _matrix(predictions, m) is not None]
    zoom = zoom_window(predictions["time"].to_numpy(dtype=np.float64))
    footer = tag(
        "footer",
        f"Written by drafttwin {results.get('drafttwin_version', '')} from the "
        "study's results.json; tables as CSV beside this file.",
    )
    body = join(
        [
            header(results),
            toc(_toc(results)),
            glance_section(results, figs["headline"]),
            data_notice(results),
            run_section(results),
            comparison_section(results, figs),
            figures_section(figs, plotted, zoom, truth=is_plant(results)),
            grid_section(results, figs),
            ablation_section(results, figs),
            calibration_section(results),
            agreement_section(results),
            Raw(physics_pays_section(results)),
            footer,
        ]
    )
    return page(TITLE, body)


def _write_csv(frame: pd.DataFrame, path: Path) -> None:
    with atomic_path(path) as tmp:
        frame.to_csv(tmp, index=False, float_format=CSV_FLOAT)


def write_report(
    out_dir: str | Path, results: Mapping[str, Any], predictions: pd.DataFrame
) -> dict[str, Path]:
    """Write ``report.html`` and the CSV tables into ``out_dir`` (each file atomically).

    Args:
        out_dir: folder to write into (created if needed).
        results: the study's results dictionary (schema in ``drafttwin.studies.paper.run``).
        predictions: the test part: ``time``, ``measured_<roller>``, optionally
            ``true_<roller>``, and ``<model>_<roller>`` per compared model.

    Returns:
        ``{"report": .../report.html, "table2": ..., "metrics": ..., "table3": ...,
        "table3_summary": ..., "grid": ...}``.
    """
    out = Path(out_dir)
    frames = {
        "table2": tables.table2(results),
        "metrics": tables.metrics_table(results),
        "table3": tables.table3(results),
        "table3_summary": tables.table3_summary(results),
        "grid": tables.grid_table(results),
    }
    text = render_html(results, predictions)
    paths: dict[str, Path] = {}
    for name, frame in frames.items():
        paths[name] = out / f"{name}.csv"
        _write_csv(frame, paths[name])
    paths["report"] = out / "report.html"
    write_text_atomic(paths["report"], text)
    return paths


STUDY_FILES = ("report.html", "table2.csv", "metrics.csv", "table3.csv", "table3_summary.csv",
               "grid.csv", "predictions.csv", "results.json")  # fmt: skip
"""The files :func:`write_study` writes in its folder (a caller refuses inputs among them)."""


def write_study(
    out_dir: Path, results: dict[str, Any], predictions: pd.DataFrame
) -> dict[str, Path]:
    """Everything a study run leaves in ``out_dir``: the report and its CSV tables,
    predictions.csv, then results.json (written last: it records how long the report took)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    files = write_report(out_dir, results, predictions)
    results["timings"]["stages"]["report"] = time.perf_counter() - t0
    with atomic_path(out_dir / "predictions.csv") as tmp:
        predictions.to_csv(tmp, index=False, float_format="%.6f")
    write_text_atomic(out_dir / "results.json", dumps_strict(results) + "\n")
    return {
        **files,
        "predictions": out_dir / "predictions.csv",
        "results": out_dir / "results.json",
    }
