"""``drafttwin reproduce``: the paper's whole study on one data set, resumably.

Stages: data (split, preprocessing, mechanistic simulation) -> grid search (Fig. 7) ->
the GRU data-driven model (cross-fitted) -> model comparison (Table 2, Fig. 8) -> ablation
over repeated tests (Table 3) -> results.json, predictions.csv, report.html and CSV tables.
Every fit is an executor task whose result is stored by configuration and data hash, so a
rerun skips finished work.
"""

from __future__ import annotations

import datetime as _dt
import math
import os
import platform
import time
from collections.abc import Callable
from itertools import combinations
from pathlib import Path
from typing import Any, TypedDict

import numpy as np
import pandas as pd
from scipy import stats

from drafttwin._constants import ROLLERS, __version__
from drafttwin.data.preprocessing import DEFAULT_TRAIN_FRACTION
from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import DataError
from drafttwin.execution.executor import Task, run_tasks
from drafttwin.execution.store import ResultStore
from drafttwin.models import make_model, persistence_forecast
from drafttwin.models.registry import get_profile
from drafttwin.studies.paper import tasks
from drafttwin.studies.paper.plan import StudyPlan, get_study_plan, grid_configs
from drafttwin.studies.paper.prepare import PreparedData, prepare

COMPARISON = ("mechanistic", "persistence", "gru", "parallel", "md-s-l")
EXTRA = ("md-s-l+d",)
ABLATION = ("md-s-l", "md-l", "md-s")
ON_CALIBRATED = ("parallel", "md-s-l")
"""The hybrids fitted again on the calibrated physics: does better physics make them better?"""
Stage = Callable[[str, int], Callable[[int, dict[str, Any], bool], None]]


class ExecutorSettings(TypedDict):
    """Where the study's tasks run (the keyword arguments of :func:`run_tasks`)."""

    executor: str
    address: str | None
    workers: int | None


class Study:
    """One study run: plan, data, output folder, executor settings and a progress hook."""

    def __init__(self, plan: str | StudyPlan = "quick", *, out_dir: str | Path = "drafttwin-study",
                 executor: str = "local", address: str | None = None, workers: int | None = None,
                 stage: Stage | None = None, preset: str = "fa320a") -> None:  # fmt: skip
        self.plan = plan if isinstance(plan, StudyPlan) else get_study_plan(plan)
        self.out = Path(out_dir)
        self.cache = self.out / "cache"
        self.store = ResultStore(self.cache / "results", base=self.out)  # artifacts relative to out
        self.exec_args: ExecutorSettings = {
            "executor": executor,
            "address": address,
            "workers": workers,
        }
        self.stage = stage or (lambda name, total: lambda i, r, cached: None)
        self.preset = preset
        self.data_name = "default"
        self.timings: dict[str, float] = {}
        self.fits: list[dict[str, Any]] = []

    # ---- plumbing ---------------------------------------------------------------------
    def _run(self, name: str, fn: Task, configs: list[dict[str, Any]]) -> list[dict[str, Any]]:
        ctx = {"_data": str(self.data_path), "_artifacts": str(self.cache / "artifacts")}
        configs = [{**ctx, **c} for c in configs]
        tick = self.stage(name, len(configs))
        t0 = time.perf_counter()
        results = run_tasks(fn, configs, store=self.store, data_digest=self.data.digest,
                            on_result=tick, **self.exec_args)  # fmt: skip
        self.timings[name] = self.timings.get(name, 0.0) + time.perf_counter() - t0
        for c, r in zip(configs, results, strict=True):
            label = c.get("model") or c.get("net") or "gru (data model)"
            # a grid point by its settings (every one read "grid: lstm seed 0")
            point = "".join(f" {k} {c[k]:g}" if k == "lr" else f" {k} {c[k]}"
                            for k in ("lr", "hidden", "layers") if k in c)  # fmt: skip
            self.fits.append(
                {"task": f"{name}: {label}{point} seed {c.get('seed')}", "wall_s": r.get("wall_s")}
            )
        return results

    def _base(self) -> dict[str, Any]:
        return {"model_profile": self.plan.model_profile}

    def _scored(self) -> dict[str, Any]:
        """Configuration of the tasks that return metrics: the metric schema is part of their
        identity, so results stored under an older schema are not reused."""
        return {**self._base(), "metric_schema": tasks.METRIC_SCHEMA}

    def _hyper(self, best: dict[str, dict[str, Any]]) -> tuple[dict[str, Any], dict[str, Any]]:
        """Hyperparameter overrides for the data-driven GRU and the residual models."""
        train = {
            k: v
            for k, v in (
                ("epochs", self.plan.epochs),
                ("patience", self.plan.patience),
                ("schedule", self.plan.schedule),
            )
            if v is not None
        }
        if not self.plan.use_grid_best:
            layers = self.plan.residual_layers
            return dict(train), {**train, **({} if layers is None else {"layers": layers})}
        g, lstm = best["gru"], best["lstm"]
        data = {**train, "data_hidden": g["hidden"], "data_layers": g["layers"], "lr": g["lr"]}
        res = {**train, "hidden": lstm["hidden"], "layers": lstm["layers"], "lr": lstm["lr"]}
        return data, res

    # ---- stages -----------------------------------------------------------------------
    def prepare_data(self, series: MeasurementSeries) -> dict[str, Any]:
        t0 = time.perf_counter()
        self.data, summary = prepare(series, train_fraction=DEFAULT_TRAIN_FRACTION, preset=self.preset, cache_dir=self.cache,
                                     duration_s=self.plan.data_duration_s)  # fmt: skip
        self._check_length()
        self.data_path = self.cache / f"data-{self.data.digest[:16]}.npz"
        saved = PreparedData.load_checked(self.data_path)
        if saved is None or saved.digest != self.data.digest:
            self.data.save(self.data_path)
        self.timings["data"] = time.perf_counter() - t0
        return summary

    def _check_length(self) -> None:
        """Refuse a record too short for the plan's models before any fit (it had failed
        after the grid, in MD-S-L's data-model folds, naming options reproduce lacks): each
        cross-fitting fold's training part needs two windows' worth of rows, over the
        validation share."""
        profile = get_profile(self.plan.model_profile)
        need = math.ceil(2 * profile.folds * (profile.window + 1) / (1 - profile.val_fraction))
        if self.data.n_train < need:
            rows = len(self.data.time_s)
            raise DataError(
                f"the record gives {self.data.n_train} training rows ({DEFAULT_TRAIN_FRACTION:.0%} "
                f"of {rows}); the study's models need at least {need}",
                source=None if self.data_name == "default" else self.data_name,
                where="--data",
                fix=f"give a record of at least {math.ceil(need / DEFAULT_TRAIN_FRACTION)} rows",
            )

    def grid(self) -> dict[str, Any]:
        window = get_profile(self.plan.model_profile).window
        configs = [{**self._base(), **c} for c in grid_configs(self.plan, window)]
        results = self._run("grid", tasks.grid_point, configs)
        rows: dict[str, list[dict[str, Any]]] = {"lstm": [], "gru": []}
        for c, r in zip(configs, results, strict=True):
            rows[c["net"]].append({k: c[k] for k in ("lr", "hidden", "layers")} | r)
        best = {net: min(r, key=lambda x: x["val_loss"]) for net, r in rows.items()}
        budget = {"epochs": self.plan.grid_epochs, "patience": self.plan.grid_patience,
                  "train_samples": self.plan.grid_train_samples, "window": window}  # fmt: skip
        return {**rows, "best": best, "budget": budget}

    def data_models(self, seeds: list[int], hyper: dict[str, Any]) -> list[dict[str, Any]]:
        configs = [{**self._scored(), "seed": s, "hyper": hyper} for s in seeds]
        return self._run("data model", tasks.data_model, configs)

    def hybrids(self, stage: str, models: list[str], seeds: list[tuple[int, int]],
                hyper: dict[str, Any], dms: dict[int, dict[str, Any]], save: bool,
                physics: str = "nominal") -> list[dict[str, Any]]:  # fmt: skip
        on = {} if physics == "nominal" else {"physics": physics}  # nominal keys stay as before
        configs = [{**self._scored(), "model": m, "seed": s, "hyper": hyper, "save_predictions": save,
                    "data_model_seed": ds, "_data_model": dms[ds], **on}
                   for m in models for s, ds in seeds]  # fmt: skip
        return self._run(stage, tasks.hybrid, configs)

    # ---- the whole study --------------------------------------------------------------
    def run(self, series: MeasurementSeries) -> tuple[dict[str, Any], pd.DataFrame]:
        t_start = time.perf_counter()
        summary = self.prepare_data(series)
        cal_report = summary.pop("calibration")
        grid = self.grid()
        data_hyper, res_hyper = self._hyper(grid["best"])
        n_tests = self.plan.ablation_tests
        dm_seeds = [0] if self.plan.shared_data_model else list(range(n_tests))
        dms = dict(zip(dm_seeds, self.data_models(dm_seeds, data_hyper), strict=True))
        comp = self.hybrids(
            "comparison", ["parallel", "md-s-l", *EXTRA], [(0, 0)], res_hyper, dms, True
        )
        pairs = [(k, 0 if self.plan.shared_data_model else k) for k in range(n_tests)]
        abl = self.hybrids("ablation", list(ABLATION), pairs, res_hyper, dms, False)
        on_cal = self.hybrids("calibrated physics", list(ON_CALIBRATED), [(0, 0)], res_hyper,
                              dms, False, physics="calibrated")  # fmt: skip
        preds = self._predictions(dms[0], comp)
        results = {
            "drafttwin_version": __version__,
            "created_utc": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
            "profile": {  # the plan, under the key the report and saved results know
                "name": self.plan.name,
                "settings": self.plan.to_dict(),
                "model_profile": get_profile(self.plan.model_profile).to_dict(),
                "data_hyper": data_hyper,
                "residual_hyper": res_hyper,
                "notes": list(self.plan.notes),
            },  # fmt: skip
            "data": {
                "name": self.data_name,
                "hash": self.data.digest,
                **summary,
                "plant_summary": plant_summary(series),
            },
            "mechanistic": {"source": f"preset {self.preset}", "wall_s": self.timings["data"]},
            "grid": grid,
            "comparison": self._comparison(dms[0], comp, preds),
            "ablation": self._ablation(abl, n_tests),
            "calibration": self._calibration(cal_report, comp, on_cal),
            "timings": {},
            "machine": machine(),
        }
        self.timings["total"] = time.perf_counter() - t_start
        results["timings"] = {"total_s": self.timings.pop("total"), "stages": dict(self.timings),
                              "fits": self.fits}  # fmt: skip
        return results, self._prediction_frame(preds)

    def _predictions(self, dm: dict[str, Any], comp: list[dict[str, Any]]) -> dict[str, np.ndarray]:
        out = {"mechanistic": self.data.mech, "persistence": persistence_forecast(self.data.inputs),
               "gru": np.load(dm["pred_path"])}  # fmt: skip
        for name, r in zip(["parallel", "md-s-l", *EXTRA], comp, strict=True):
            out[name] = np.load(r["pred_path"])
        return out

    def _comparison(
        self, dm: dict[str, Any], comp: list[dict[str, Any]], preds: dict[str, np.ndarray]
    ) -> dict[str, Any]:
        metrics = {
            name: tasks.score(self.data, preds[name], make_model(name))
            for name in ("mechanistic", "persistence")
        }
        metrics["gru"] = dm["metrics"]
        for name, r in zip(["parallel", "md-s-l", *EXTRA], comp, strict=True):
            metrics[name] = r["metrics"]
        return {"models": list(COMPARISON), "extra": list(EXTRA), "metrics": metrics}

    def _calibration(
        self, report: dict[str, Any], comp: list[dict[str, Any]], on_cal: list[dict[str, Any]]
    ) -> dict[str, Any]:
        """Nominal against calibrated physics, alone and under each hybrid (same seeds)."""
        nominal = dict(zip(["parallel", "md-s-l", *EXTRA], comp, strict=True))
        mech = make_model("mechanistic")
        metrics = {
            "nominal": {"mechanistic": tasks.score(self.data, self.data.mech, mech),
                        **{m: nominal[m]["metrics"] for m in ON_CALIBRATED}},
            "calibrated": {"mechanistic": tasks.score(self.data, self.data.physics("calibrated"), mech),
                           **{m: r["metrics"] for m, r in zip(ON_CALIBRATED, on_cal, strict=True)}},
        }  # fmt: skip
        return {"models": ["mechanistic", *ON_CALIBRATED], "report": report, "metrics": metrics,
                "note": "calibrated on the training part only (drafttwin calibrate, default "
                        "parameters, reduced model); the same seeds on both physics"}  # fmt: skip

    def _ablation(self, abl: list[dict[str, Any]], n_tests: int) -> dict[str, Any]:
        acc = {v: [[abl[i * n_tests + k]["metrics"][r]["accuracy_pct"] for r in ROLLERS]
                   for k in range(n_tests)] for i, v in enumerate(ABLATION)}  # fmt: skip
        rmse = {v: [[abl[i * n_tests + k]["metrics"][r]["rmse"] for r in ROLLERS]
                    for k in range(n_tests)] for i, v in enumerate(ABLATION)}  # fmt: skip
        summary = {
            v: {r: _describe(np.array(acc[v], dtype=float)[:, j]) for j, r in enumerate(ROLLERS)}
            for v in ABLATION
        }
        diffs = []
        for a, b in combinations(ABLATION, 2):
            for j, r in enumerate(ROLLERS):
                xa, xb = np.array(acc[a], dtype=float)[:, j], np.array(acc[b], dtype=float)[:, j]
                spread = float(np.sqrt((xa.var(ddof=1) + xb.var(ddof=1)) / 2))
                diff = float(xa.mean() - xb.mean())
                p = (
                    float(stats.ttest_ind(xa, xb, equal_var=False).pvalue)
                    if spread > 0
                    else float("nan")
                )
                diffs.append({"a": a, "b": b, "roller": r, "metric": "accuracy_pct", "mean_diff": diff,
                              "spread": spread, "larger_than_spread": abs(diff) > spread, "welch_p": p})  # fmt: skip
        return {"variants": list(ABLATION), "seeds": list(range(n_tests)),
                "spread_definition": "pooled standard deviation of the two variants over the repeated "
                                     "tests, sqrt((s_a^2 + s_b^2) / 2); Welch's t-test p-value beside it",
                "shared_data_model": self.plan.shared_data_model, "accuracy": acc, "rmse": rmse,
                "summary": summary, "differences": diffs}  # fmt: skip

    def _prediction_frame(self, preds: dict[str, np.ndarray]) -> pd.DataFrame:
        tr = self.data.n_train
        cols: dict[str, np.ndarray] = {"time": self.data.time_s[tr:]}
        for j, r in enumerate(ROLLERS):
            cols[f"measured_{r}"] = self.data.target[tr:, j]
            if self.data.true is not None:
                cols[f"true_{r}"] = self.data.true[tr:, j]
        for name, p in preds.items():
            for j, r in enumerate(ROLLERS):
                cols[f"{name}_{r}"] = p[tr:, j]
        return pd.DataFrame(cols)


def plant_summary(series: MeasurementSeries) -> list[str]:
    """What the data are, in a few lines for the report (empty for real measurements)."""
    plant = series.metadata.get("plant")
    if not plant:
        return []
    inj = plant.get("injected", {})
    return [
        f"Plant emulator (drafttwin {__version__}), scenario '{plant.get('scenario')}', seed {plant.get('seed')}: "
        "the FA320A drive-train model with true parameters drawn around the nominal preset "
        "(friction, belt creep, mesh and roller stiffness, motor curve, bearing friction).",
        "Adds what the mechanistic model leaves out: gear backlash (80 um, change-gear rattle), gear "
        "eccentricity, drafting force of the sliver (colored), roller run-out, thermal drift of "
        "motor slip, VFD frequency jitter.",
        f"Measured by 2500-ppr quadrature encoders counting over each 10 ms window (0.6 rpm step), "
        f"with {inj.get('missing_rows', '?')} dropped rows and {sum(inj.get('outliers', {}).values())} "
        "spikes injected; the true speeds are kept, so the encoders' error and the one-step floor "
        "are known.",
        "Left out: top-roller and fibre slip (they change sliver speed, not bottom-roller speed), "
        "cot wear, autoleveller action, any real machine's unknown unknowns.",
    ]


def _describe(x: np.ndarray) -> dict[str, float]:
    return {"mean": float(x.mean()), "std": float(x.std(ddof=1)) if len(x) > 1 else 0.0,
            "min": float(x.min()), "max": float(x.max())}  # fmt: skip


def machine() -> dict[str, Any]:
    import torch

    return {"cpu": platform.processor() or platform.machine(), "logical_cores": os.cpu_count(),
            "python": platform.python_version(), "torch": torch.__version__,
            "device": "cuda" if torch.cuda.is_available() else "cpu"}  # fmt: skip
