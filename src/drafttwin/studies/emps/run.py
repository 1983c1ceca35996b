"""The EMPS benchmark: physics, black-box and hybrid models on real measurements.

Official protocol (``nonlinear_benchmarks.EMPS`` v1.0.1): train on ``DATA_EMPS``, test on
``DATA_EMPS_PULSES``, input ``vir`` (V), output ``qm`` (m), free-run simulation that may use
only ``test.y[:20]``, RMSE over ``test.y[20:]`` in mm. Every model also runs in drafttwin's
prediction mode (one step ahead from measured history), reported apart: those
numbers are not comparable with the simulation-mode literature.

:func:`run_benchmark` runs one task per (task, model, seed) through
:func:`drafttwin.execution.run_tasks` (a process pool with ``workers > 1``) and returns the
results dict written to ``emps_results.json``; the seed-0 test predictions come back in
``traces`` for the report's figure.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from drafttwin._constants import __version__
from drafttwin.datasets.emps import INIT_SAMPLES, OUTPUT, SHA256, EmpsRecord, load_emps
from drafttwin.execution.executor import run_tasks
from drafttwin.studies.emps.physics import EmpsPhysics, PhysicsRefit, fit_pct, refit
from drafttwin.studies.emps.plan import (
    PREDICTION_START,
    PROFILE_ADAPTATION,
    PUBLISHED,
    EmpsConfig,
    score_start,
    task_configs,
    variant_name,
)
from drafttwin.studies.emps.summary import summarise


def run_one(cfg: dict[str, Any]) -> dict[str, Any]:
    """Fit one model on the training record and score it on the test record with the
    evaluation protocol (a task for :func:`run_tasks`; module level so worker processes can
    run it)."""
    import torch

    from drafttwin.evaluation import protocol
    from drafttwin.models import make_model

    torch.set_num_threads(int(cfg.get("_threads", 1)))
    train, test, _ = load_emps(cfg.get("_data_dir"))
    train, test = train.head(cfg["max_samples"]), test.head(cfg["max_samples"])
    mech = EmpsPhysics(**cfg["physics"]).mechanistic()
    model = make_model(cfg["model"], cfg["profile"], **cfg["hyper"])
    start = time.perf_counter()
    part = protocol.fit_split(model, train.series(), test=test.series(), mechanistic=mech)
    fit_s = time.perf_counter() - start
    first = score_start(cfg["task"])
    start = time.perf_counter()
    result = protocol.evaluate(model, part, mechanistic=mech, skip_rows=first)
    predict_s = time.perf_counter() - start
    pred = result.predictions[OUTPUT].to_numpy()
    history = getattr(model, "history_", None)
    out: dict[str, Any] = {
        "task": cfg["task"], "model": cfg["model"], "seed": cfg["seed"],
        "physics": cfg.get("_physics_name"),
        "rmse_mm": 1e3 * result.metrics[OUTPUT].rmse, "fit_pct": fit_pct(test.qm_m, pred, first),
        "n_nan": int(np.isnan(pred[first:]).sum()), "fit_s": fit_s, "predict_s": predict_s,
        "epochs": None if history is None else len(history.train_loss),
        "selection": dict(model.selection_),
    }  # fmt: skip
    if cfg["train_metrics"]:
        on_train = protocol.evaluate(model, test=train.series(), mechanistic=mech, skip_rows=first)
        out["train_rmse_mm"] = 1e3 * on_train.metrics[OUTPUT].rmse
    if cfg["trace"]:
        out["trace"] = pred.tolist()
    return out


@dataclass
class EmpsResult:
    """What :func:`run_benchmark` returns: the JSON-able ``results`` and the seed-0 test
    predictions ``traces[(task, name)]`` (m; ``name`` from
    :func:`~drafttwin.studies.emps.plan.variant_name`) with the measured
    ``test_qm_m``/``test_time_s``."""

    results: dict[str, Any]
    traces: dict[tuple[str, str], np.ndarray]
    test_time_s: np.ndarray
    test_qm_m: np.ndarray


def run_benchmark(
    config: EmpsConfig, progress: Callable[[dict[str, Any]], None] | None = None
) -> EmpsResult:
    """Run the benchmark; ``progress(result)`` is called as each task finishes."""
    config.check()
    train, test, folder = load_emps(config.data_dir)  # refuses missing/altered files first
    start = time.perf_counter()
    fitted = refit_on_training(config, train) if "refitted" in config.physics_variants else None
    configs = task_configs(config, None if fitted is None else fitted.physics)

    def done(i: int, result: dict[str, Any], cached: bool) -> None:
        if progress is not None:
            progress(result)

    results = run_tasks(run_one, configs, workers=config.workers, on_result=done)
    wall = time.perf_counter() - start
    traces = {(r["task"], variant_name(r["model"], r["physics"])): np.asarray(r.pop("trace"))
              for r in results if "trace" in r}  # fmt: skip
    test = test.head(config.max_samples)
    doc = {
        "benchmark": "emps",
        "drafttwin_version": __version__,
        "protocol": {
            "train": "DATA_EMPS",
            "test": "DATA_EMPS_PULSES",
            "input": "vir (V)",
            "output": "qm (m)",
            "init_samples": INIT_SAMPLES,
            "metric": "RMSE in mm over test rows 20.. (simulation; prediction from row "
            f"{PREDICTION_START})",
            "max_samples": config.max_samples,
        },
        "data": {
            "dir": str(folder),
            "sha256": dict(SHA256),
            "train_samples": len(train),
            "test_samples": len(test),
        },
        "profile": config.profile,
        "profile_adaptation": PROFILE_ADAPTATION[config.profile],
        "epochs_override": config.epochs,
        "seeds": list(range(config.seeds)),
        "physics": config.physics.to_dict(),
        "physics_variants": list(config.physics_variants),
        "physics_refit": None if fitted is None else fitted.to_dict(),
        "hyperparameters": {
            f"{c['task']}/{c['model']}": _plain(c["hyper"]) for c in configs if c["seed"] == 0
        },
        "rows": summarise(results, config),
        "runs": results,
        "published": PUBLISHED,
        "wall_s": wall,
        "workers": config.workers,
    }
    return EmpsResult(doc, traces, test.time_s, test.qm_m)


def refit_on_training(config: EmpsConfig, train: EmpsRecord) -> PhysicsRefit:
    """The physics refitted by output error on the training record (cut to
    ``config.max_samples``) from the published values; the test record is never read."""
    train = train.head(config.max_samples)
    return refit(train.vir_v, train.qm_m, config.physics, start=INIT_SAMPLES)


def _plain(hyper: dict[str, Any]) -> dict[str, Any]:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in hyper.items()}
