"""``drafttwin benchmark generalisation``: where does the physics pay?

Each learned model is trained on steady running of one machine at the preset's set-point and
tested on plant records its training never saw (:mod:`.records`), in both tasks (one-step
prediction; free-run simulation from the set-point with a short measured start). The
physics is simulated per record from the set-point it follows (and the gear set the record
was made with); the learned models see the set-point as an input and the data.

What runs is :mod:`.plan`'s. :func:`run_benchmark` returns the JSON document: ``rows`` (one per
scenario, task, model, training length, seed and channel), ``floors`` (:func:`floors`), and the
summaries (:mod:`.summary`).
"""

from __future__ import annotations

import hashlib
import json
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from drafttwin._constants import ROLLERS, __version__
from drafttwin._io import json_number, sha256_file
from drafttwin._json import dumps_strict
from drafttwin.data.preprocessing import preprocess
from drafttwin.data.series import MeasurementSeries
from drafttwin.evaluation.limits import lag1_autocorrelation
from drafttwin.evaluation.protocol import OUTLIER_THRESHOLD
from drafttwin.execution import integrity
from drafttwin.execution.executor import run_tasks
from drafttwin.execution.store import ResultStore, code_fingerprint
from drafttwin.models.estimators.hybrid import FADES, STRUCTURES
from drafttwin.studies.generalisation import records as R
from drafttwin.studies.generalisation.fits import (
    load_records,
    run_fit,
    save_records,
)
from drafttwin.studies.generalisation.plan import (
    CALIBRATED_SCENARIOS,
    GeneralisationConfig,
    fit_configs,
    selection_configs,
    skip_options,
)
from drafttwin.studies.generalisation.summary import summarise

Progress = Callable[[str, int, int], None]
"""``progress(stage, done, total)``."""


def make_records(config: GeneralisationConfig, progress: Progress | None = None
                 ) -> dict[str, MeasurementSeries]:  # fmt: skip
    """The training, validation and test records (plant emulator runs)."""
    specs = [("train", R.TRAIN_RECORD, config.train_s)]
    specs += [(k, v, config.validation_s) for k, v in R.VALIDATION_RECORDS.items()]
    specs += [(s, R.TEST_RECORDS[s], config.test_s) for s in config.scenarios]
    out = {}
    for i, (key, spec, duration) in enumerate(specs):
        out[key] = R.make_record(spec, duration, config.rate_hz)
        if progress:
            progress("plant records", i + 1, len(specs))
    return out


def make_physics(
    config: GeneralisationConfig,
    records: dict[str, MeasurementSeries],
    progress: Progress | None = None,
) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, Any]]:
    """The nominal physics of every record (its gear set, its set-points) and the physics
    calibrated on the first ``calibrate_s`` of the training record where it is scored."""
    from drafttwin.calibration import calibrate
    from drafttwin.mechanics import reduce
    from drafttwin.models import MechanisticModel

    physics: dict[str, dict[str, np.ndarray]] = {}
    gears = {name: R.TEST_RECORDS[name].draft_gears if name in R.TEST_RECORDS else False
             for name in records}  # fmt: skip
    for i, (name, series) in enumerate(records.items()):
        train = R.nominal_train(gears[name])
        physics[name] = {"nominal": MechanisticModel.from_train(train).predict_values(series)}
        if progress:
            progress("physics", i + 1, len(records) + 1)
    start = time.perf_counter()
    calib_rows = int(round(config.calibrate_s * config.rate_hz))
    result = calibrate(R.nominal_train(), records["train"].slice(0, calib_rows),
                       config.calibrate_params, model=reduce, model_name="reduced")  # fmt: skip
    calibrated = MechanisticModel.from_train(result.train)
    for name in ("train", *(s for s in CALIBRATED_SCENARIOS if s in records)):
        physics[name]["calibrated"] = calibrated.predict_values(records[name])
    info = {"calibrated_on_s": config.calibrate_s, "wall_s": time.perf_counter() - start,
            "rmse_before": result.rmse_before, "rmse_after": result.rmse_after,
            "parameters": [e.name for e in result.estimates]}  # fmt: skip
    if progress:
        progress("physics", len(records) + 1, len(records) + 1)
    return physics, info


def choose_structures(rows: list[dict[str, Any]]) -> dict[tuple[str, str], dict[str, Any]]:
    """Per (hybrid, task), the structure, fade and skip with the lowest validation score: the
    mean over validation records and channels of the hybrid's RMSE over its physics' RMSE on
    the same record (below 1: the hybrid improves on its physics). Candidates are tried
    simplest first and a later one must be strictly better."""
    out: dict[tuple[str, str], dict[str, Any]] = {}
    physics = {(r["task"], r["scenario"], r["channel"]): r["rmse"] for r in rows
               if r["model"] == "mechanistic"}  # fmt: skip
    keys = sorted({(r["model"], r["task"]) for r in rows if r["model"] != "mechanistic"})
    for model, task in keys:
        scores: list[dict[str, Any]] = []
        for skip in skip_options(task):
            for structure in STRUCTURES:
                for fade in FADES:
                    cand = {"structure": structure, "fade": fade, "skip": skip}
                    mine = [r for r in rows if (r["model"], r["task"]) == (model, task)
                            and all(r.get(k) == v for k, v in cand.items())]  # fmt: skip
                    scores.append({**cand, "score": _validation_score(mine, physics, task)})
        best = scores[0]
        for cand in scores[1:]:
            if cand["score"] < best["score"]:
                best = cand
        out[(model, task)] = {"structure": best["structure"], "fade": best["fade"],
                              "skip": best["skip"], "scores": scores}  # fmt: skip
    return out


def _validation_score(
    mine: list[dict[str, Any]], physics: dict[tuple[str, str, str], float], task: str
) -> float:
    """Mean RMSE / physics RMSE over the rows of one candidate (inf if any is missing)."""
    ratios = []
    for r in mine:
        ref = physics.get((task, r["scenario"], r["channel"]))
        if ref is not None and _finite(r["rmse"]) and _finite(ref) and ref > 0:
            ratios.append(r["rmse"] / ref)
    return float(np.mean(ratios)) if len(ratios) == len(mine) and mine else np.inf


def floors(
    config: GeneralisationConfig, path: Path, rows: list[dict[str, Any]]
) -> list[dict[str, Any]]:
    """Per channel: the best one-step RMSE any run scored on the little-data test record
    (steady, the training set-point; every seed counts) and its floor, the project's one-step
    floor oracle on that run's scored samples (:mod:`drafttwin.evaluation.limits`), with every
    run that scored below its own floor (none, unless the floor is wrong)."""
    if "little-data" not in config.scenarios or "prediction" not in config.tasks:
        return []
    lag1 = _sensor_error_lag1(path, "little-data")
    out = []
    for channel in ROLLERS:
        runs = [r for r in rows if r["scenario"] == "little-data" and r["task"] == "prediction"
                and r["channel"] == channel and _finite(r["rmse"])]  # fmt: skip
        best = min(runs, key=lambda r: r["rmse"]) if runs else None
        below = sorted({f"{r['model']}@{r['train_s']}s/seed{r['seed']}" for r in runs
                        if _finite(r.get("rmse_floor")) and r["rmse"] < r["rmse_floor"]})  # fmt: skip
        out.append({"channel": channel,
                    "floor": None if best is None else best.get("rmse_floor"),
                    "best_model": None if best is None else best["model"],
                    "best_rmse": None if best is None else float(best["rmse"]),
                    "best_train_s": None if best is None else best["train_s"],
                    "best_seed": None if best is None else best["seed"],
                    "below_floor": below,
                    # why the oracle may give no floor: its premise is -1/2 (evaluation.limits)
                    "sensor_error_lag1": json_number(lag1[channel]),
                    "floor_kind": "one-step floor oracle (evaluation.limits): true speed and "
                    "every earlier measurement known, on the best run's scored samples"})  # fmt: skip
    return out


def _sensor_error_lag1(path: Path, record: str) -> dict[str, float]:
    """Per channel: the lag-one autocorrelation of ``record``'s sensor errors (measured minus
    true speed) on the rows the runs are scored on (the paper's outliers left out: a few
    spikes of a 3-rpm spread made a counting encoder's -0.5 read -0.008), the figure the
    floor oracle's counting premise rests on."""
    series = load_records(path)[0][record]
    err = np.asarray(series.values, float) - np.asarray(series.truth, float)
    err[preprocess(series, outlier_threshold=OUTLIER_THRESHOLD)[1].outliers] = np.nan
    return {c: lag1_autocorrelation(err[:, j]) for j, c in enumerate(series.channels)}


def _records_key(config: GeneralisationConfig) -> str:
    """What the records and physics depend on (a cached file is reused only for the same)."""
    from drafttwin.mechanics.config import preset_path

    keep = {k: v for k, v in asdict(config).items() if k in (
        "train_lengths_s", "test_s", "validation_s", "rate_hz", "calibrate_s", "calibrate_params",
        "scenarios")}  # fmt: skip
    text = json.dumps(keep, sort_keys=True) + code_fingerprint() + str(R.DRAFT_GEARS)
    digest = hashlib.sha256(text.encode() + preset_path("fa320a").read_bytes())
    return digest.hexdigest()[:16]


def prepare_records(config: GeneralisationConfig, folder: Path,
                    progress: Progress | None = None) -> tuple[Path, dict[str, Any]]:  # fmt: skip
    """The records and their physics in ``folder`` (reused when a checked file of the same
    configuration is there), and what the benchmark reports about them."""
    path = folder / f"records-{_records_key(config)}.npz"
    about = folder / f"{path.stem}.json"
    info = integrity.read_checked(about, lambda p: json.loads(p.read_text(encoding="utf-8")))
    if info is not None and integrity.read_checked(path, load_records) is not None:
        return path, info
    records = make_records(config, progress)
    physics, calibration = make_physics(config, records, progress)
    save_records(path, records, physics, sealed=True)
    info = {"records": {name: _describe(name, s) for name, s in records.items()},
            "calibration": calibration}  # fmt: skip
    integrity.write_text_sealed(about, dumps_strict(info))
    return path, info


def run_benchmark(config: GeneralisationConfig, progress: Progress | None = None,
                  cache_dir: Path | None = None) -> dict[str, Any]:  # fmt: skip
    """Run the benchmark; ``progress(stage, done, total)`` reports each step. With
    ``cache_dir``, the records and every finished fit are kept there (checked when read
    back), so a rerun of the same configuration reuses them."""
    config.check()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="drafttwin-gen-") as tmp:
        folder = Path(cache_dir) if cache_dir is not None else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        path, info = prepare_records(config, folder, progress)
        timings = {"records_and_physics_s": time.perf_counter() - t0}
        store = ResultStore(folder / "fits") if cache_dir is not None else None
        digest = sha256_file(path)
        t1 = time.perf_counter()
        selected = _fits(selection_configs(config, path), config, "structure choice", progress,
                         store, digest)  # fmt: skip
        chosen = choose_structures([row for r in selected for row in r["rows"]])
        timings["structure_choice_s"] = time.perf_counter() - t1
        t1 = time.perf_counter()
        extra = {k: {"structure": v["structure"], "fade": v["fade"], "skip": v["skip"]}
                 for k, v in chosen.items()}  # fmt: skip
        results = _fits(fit_configs(config, path, extra), config, "model fits", progress,
                        store, digest)  # fmt: skip
        timings["fits_s"] = time.perf_counter() - t1
        rows = [row for r in results for row in r["rows"]]
        floor_rows = floors(config, path, rows)
    timings["total_s"] = time.perf_counter() - t0
    doc: dict[str, Any] = {
        "rows": rows,
        "floors": floor_rows,
        "benchmark": "generalisation",
        "drafttwin_version": __version__,
        "config": asdict(config),
        "records": info["records"],
        "calibration": info["calibration"],
        "structure_choice": [{"model": m, "task": t, **v} for (m, t), v in chosen.items()],
        "fits": [
            {k: r[k] for k in ("model", "task", "train_s", "seed", "fit_s", "selection")}
            for r in results
        ],  # fmt: skip
        "timings": timings,
    }
    doc |= summarise(rows, config.train_s)
    return doc


def _fits(configs: list[dict[str, Any]], config: GeneralisationConfig, stage: str,
          progress: Progress | None, store: ResultStore | None, digest: str) -> list[dict[str, Any]]:  # fmt: skip
    count = [0]

    def done(i: int, result: dict[str, Any], cached: bool) -> None:
        count[0] += 1
        if progress:
            progress(stage, count[0], len(configs))

    return run_tasks(run_fit, configs, workers=config.workers, on_result=done, store=store,
                     data_digest=digest)  # fmt: skip


def _finite(x: Any) -> bool:
    return x is not None and bool(np.isfinite(x))


def _describe(name: str, series: MeasurementSeries) -> dict[str, Any]:
    spec = {"train": R.TRAIN_RECORD, **R.VALIDATION_RECORDS, **R.TEST_RECORDS}[name]
    return {"what": spec.describe(), "duration_s": series.duration_s, "rows": len(series),
            "mean_true_rpm": dict(zip(ROLLERS, np.nanmean(series.truth, axis=0).tolist(),
                                      strict=True)) if series.truth is not None else None}  # fmt: skip
