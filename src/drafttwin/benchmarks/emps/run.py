"""The EMPS benchmark: physics, black-box and hybrid models on real measurements.

Official protocol (``nonlinear_benchmarks.EMPS`` v1.0.1): train on ``DATA_EMPS``, test on
``DATA_EMPS_PULSES``, input ``vir`` (V), output ``qm`` (m), free-run simulation that may use
only ``test.y[:20]``, RMSE over ``test.y[20:]`` in mm. Every model also runs in drafttwin's
prediction mode (one step ahead from measured history), reported apart: those
numbers are not comparable with the simulation-mode literature.

:func:`run_benchmark` runs one task per (task, model, seed) through
:func:`drafttwin.experiments.run_tasks` (a process pool with ``workers > 1``) and returns the
results dict written to ``emps_results.json``; the seed-0 test predictions come back in
``traces`` for the report's figure.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypedDict

import numpy as np

from drafttwin._constants import __version__
from drafttwin.benchmarks.emps.physics import EmpsPhysics, fit_pct
from drafttwin.datasets.emps import INIT_SAMPLES, INPUT, OUTPUT, SHA256, load_emps
from drafttwin.errors import ConfigError
from drafttwin.execution.executor import run_tasks

MODELS = ("mechanistic", "persistence", "gru", "lstm", "parallel", "md-s-l")
"""Models of the benchmark; ``mechanistic`` is the physics-only model."""
TASKS = ("simulation", "prediction")
DETERMINISTIC = ("mechanistic", "persistence")
"""Models without training: run once per task, not once per seed."""

WINDOW = INIT_SAMPLES
"""Input window of every network: the 20-sample initialisation window of the protocol."""
PREDICTION_START = INIT_SAMPLES + WINDOW
"""First scored row in prediction mode: MD-S-L's residual windows need ``WINDOW`` rows of
the GRU's predictions, which themselves start at row ``WINDOW``."""

PROFILE_ADAPTATION: dict[str, dict[str, Any]] = {
    "quick": {"stride": 5},
    "standard": {"stride": 2},
    "paper": {},
}
"""EMPS changes to the drafttwin profiles (beside the 20-sample windows): the records hold
25,000 samples at 1 kHz, so the quick and standard profiles train on every 5th / 2nd
window (neighbouring windows differ by one sample of 20)."""


class Published(TypedDict):
    """A literature result: the RMSE (mm) and where it comes from."""

    rmse_mm: float
    source: str


PUBLISHED: dict[str, Published] = {
    "mechanistic": {
        "rmse_mm": 9.23,
        "source": "computed in the data set's README (RK4, 10 steps per ms, ZOH vir, q(0) = "
        "qm(0), q'(0) = 0, symmetric IDIM-LS parameters of Janot et al. 2019); not a "
        "published number",
    },
    "lstm": {
        "rmse_mm": 74.1,
        "source": "Champneys et al. 2024, IFAC-PapersOnLine 58(15), companion repository "
        "MDCHAMP/nonlinear_baselines: trained on the first half of DATA_EMPS, validated on the "
        "second half; test-output std 82.7 mm, so these models barely beat the mean",
    },
    "gru": {"rmse_mm": 220.3, "source": "Champneys et al. 2024 (as LSTM)"},
}
"""Literature numbers for the simulation task, from the data set's README (with caveats)."""


@dataclass(frozen=True)
class EmpsConfig:
    """What :func:`run_benchmark` runs.

    Attributes:
        data_dir: folder of the EMPS files (``None``: search, see :mod:`.emps_data`).
        seeds: number of seeds (0 .. seeds-1) for the trained models.
        profile: drafttwin training profile (quick, standard, paper).
        models / tasks: subsets of :data:`MODELS` / :data:`TASKS`.
        epochs: override of the profile's epoch budget (``None``: the profile's).
        max_samples: use only the first samples of each record (smoke tests; the official
            protocol uses all).
        train_metrics: also score the free run / predictions on the training record.
        workers: parallel processes (1: in this process).
        device: torch device for the networks.
    """

    data_dir: Path | None = None
    seeds: int = 3
    profile: str = "quick"
    models: tuple[str, ...] = MODELS
    tasks: tuple[str, ...] = TASKS
    epochs: int | None = None
    max_samples: int | None = None
    train_metrics: bool = False
    workers: int = 1
    device: str = "auto"
    physics: EmpsPhysics = field(default_factory=EmpsPhysics)

    def check(self) -> None:
        """Refuse unknown models, tasks, profiles and out-of-range numbers (ConfigError)."""
        from drafttwin.models import get_profile

        get_profile(self.profile)
        for what, values, allowed in (("--models", self.models, MODELS),
                                      ("--tasks", self.tasks, TASKS)):  # fmt: skip
            bad = [v for v in values if v not in allowed]
            if bad or not values:
                raise ConfigError(f"unknown or no entries {bad}", where=what,
                                  fix=f"use a comma-separated subset of {', '.join(allowed)}")  # fmt: skip
        if self.seeds < 1 or self.workers < 1 or (self.epochs is not None and self.epochs < 1):
            raise ConfigError("seeds, workers and epochs must be >= 1", where="options")
        if self.max_samples is not None and self.max_samples < 4 * (INIT_SAMPLES + WINDOW):
            raise ConfigError(f"--max-samples {self.max_samples} is too short",
                              where="--max-samples",
                              fix=f"use at least {4 * (INIT_SAMPLES + WINDOW)} samples")  # fmt: skip


def hyperparameters(name: str, task: str, config: EmpsConfig, seed: int) -> dict[str, Any]:
    """Options of model ``name`` for :func:`~drafttwin.models.make_model` in the benchmark
    (profile + EMPS settings); the models without learning take the task only."""
    wanted: dict[str, Any] = {"task": task, "outputs": (OUTPUT,)}
    if task == "simulation":
        wanted["init_samples"] = INIT_SAMPLES
    if name in DETERMINISTIC:
        return wanted
    wanted |= {"inputs": (INPUT,), "window": WINDOW, "seed": seed, "quiet": True,
               "device": config.device, **PROFILE_ADAPTATION[config.profile]}  # fmt: skip
    if name in ("md-s-l", "md-l", "md-s", "md-s-l+d"):
        wanted["data_window"] = WINDOW
    if config.epochs is not None:
        wanted["epochs"] = config.epochs
    return wanted


def task_configs(config: EmpsConfig) -> list[dict[str, Any]]:
    """One configuration per (task, model, seed); deterministic models get seed 0 only."""
    out = []
    for task in config.tasks:
        for name in config.models:
            seeds = [0] if name in DETERMINISTIC else range(config.seeds)
            for seed in seeds:
                out.append({
                    "task": task, "model": name, "seed": seed, "profile": config.profile,
                    "hyper": hyperparameters(name, task, config, seed),
                    "max_samples": config.max_samples, "train_metrics": config.train_metrics,
                    "physics": config.physics.to_dict(), "trace": seed == 0,
                    "_data_dir": None if config.data_dir is None else str(config.data_dir),
                    "_threads": max(1, _cpus() // config.workers),
                })  # fmt: skip
    return out


def _cpus() -> int:
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def score_start(task: str) -> int:
    """First scored test row: 20 (simulation, official) or 40 (prediction, see above)."""
    return INIT_SAMPLES if task == "simulation" else PREDICTION_START


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
    part = protocol.fit(model, train.series(), test=test.series(), mechanistic=mech)
    fit_s = time.perf_counter() - start
    first = score_start(cfg["task"])
    start = time.perf_counter()
    result = protocol.evaluate(model, part, mechanistic=mech, skip_rows=first)
    predict_s = time.perf_counter() - start
    pred = result.predictions[OUTPUT].to_numpy()
    history = getattr(model, "history_", None)
    out: dict[str, Any] = {
        "task": cfg["task"], "model": cfg["model"], "seed": cfg["seed"],
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


def summarise(results: Sequence[dict[str, Any]], config: EmpsConfig) -> list[dict[str, Any]]:
    """One row per (task, model): RMSE over seeds (mean, std, min, max) and the rest."""
    rows = []
    for task in config.tasks:
        for name in config.models:
            runs = [r for r in results if r["task"] == task and r["model"] == name]
            if not runs:
                continue
            rmse = np.array([r["rmse_mm"] for r in runs])
            row: dict[str, Any] = {
                "task": task, "model": name, "runs": len(runs),
                "rmse_mm": rmse.tolist(), "rmse_mm_mean": float(rmse.mean()),
                "rmse_mm_std": float(rmse.std(ddof=1)) if len(runs) > 1 else 0.0,
                "rmse_mm_min": float(rmse.min()), "rmse_mm_max": float(rmse.max()),
                "fit_pct_mean": float(np.mean([r["fit_pct"] for r in runs])),
                "fit_s_mean": float(np.mean([r["fit_s"] for r in runs])),
                "predict_s_mean": float(np.mean([r["predict_s"] for r in runs])),
                "n_nan": int(max(r["n_nan"] for r in runs)),
                "score_from_row": score_start(task),
            }  # fmt: skip
            if all("train_rmse_mm" in r for r in runs):
                row["train_rmse_mm_mean"] = float(np.mean([r["train_rmse_mm"] for r in runs]))
            if task == "simulation" and name in PUBLISHED:
                row["published_rmse_mm"] = PUBLISHED[name]["rmse_mm"]
            rows.append(row)
    return rows


@dataclass
class EmpsResult:
    """What :func:`run_benchmark` returns: the JSON-able ``results`` and the seed-0 test
    predictions ``traces[(task, model)]`` (m) with the measured ``test_qm_m``/``test_time_s``."""

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
    configs = task_configs(config)
    start = time.perf_counter()

    def done(i: int, result: dict[str, Any], cached: bool) -> None:
        if progress is not None:
            progress(result)

    results = run_tasks(run_one, configs, workers=config.workers, on_result=done)
    wall = time.perf_counter() - start
    traces = {(r["task"], r["model"]): np.asarray(r.pop("trace")) for r in results
              if "trace" in r}  # fmt: skip
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


def _plain(hyper: dict[str, Any]) -> dict[str, Any]:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in hyper.items()}
