"""The study end to end on a tiny budget: shapes of every table, resume from the cache."""

import json
from dataclasses import replace

import numpy as np
import pytest

from drafttwin import ROLLERS
from drafttwin.datasets import load_default
from drafttwin.report import write_study
from drafttwin.studies.paper.plan import STUDY_PLANS
from drafttwin.studies.paper.run import Study

TINY = replace(STUDY_PLANS["quick"], name="tiny", data_duration_s=24.0, epochs=1, patience=None,
               grid_epochs=1, grid_train_samples=300, ablation_tests=10)  # fmt: skip


@pytest.fixture(scope="module")
def study_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("study")
    runs = []

    def stage(name, total):
        return lambda i, r, cached: runs.append((name, cached))

    study = Study(TINY, out_dir=out, workers=2, stage=stage)
    results, predictions = study.run(load_default())
    files = write_study(out, results, predictions)
    return out, results, predictions, files, runs


def test_results_hold_every_table(study_run):
    _, results, predictions, _, _ = study_run
    comp = results["comparison"]["metrics"]
    assert list(results["comparison"]["models"]) == [
        "mechanistic",
        "persistence",
        "gru",
        "parallel",
        "md-s-l",
    ]
    for model in results["comparison"]["models"]:
        assert set(comp[model]) == set(ROLLERS)
        for m in comp[model].values():
            assert {
                "max_rel_err_pct",
                "mean_rel_err_pct",
                "rmse",
                "nrmse",
                "skill",
                "rmse_floor",
                "rmse_vs_true",
                "sensor_rmse",
                "true_error_ratio",
                "rel_threshold",
                "n_rel_excluded",
                "rel_note",
            } <= set(m)
            assert m["unit"] == "rpm" and m["rel_note"] is None
    acc = results["ablation"]["accuracy"]
    assert set(acc) == {"md-s-l", "md-l", "md-s"}
    assert all(np.array(v).shape == (10, 4) for v in acc.values())
    assert len(results["grid"]["lstm"]) == 18 and len(results["grid"]["gru"]) == 18
    assert len(results["ablation"]["differences"]) == 3 * 4
    assert {f"md-s-l_{r}" for r in ROLLERS} <= set(predictions.columns)


def test_metrics_are_consistent(study_run):
    _, results, _, _, _ = study_run
    comp = results["comparison"]["metrics"]
    for r in ROLLERS:
        assert comp["persistence"][r]["skill"] == pytest.approx(0.0, abs=1e-12)
        # the limits hold: no model scores below the floor on its own scored samples, and
        # the floor lies below the encoders' own error (part of it can be foreseen)
        for m in results["comparison"]["models"]:
            row = comp[m][r]
            assert row["rmse_floor"] < row["sensor_rmse"] < 1.5 * row["rmse_floor"]
            assert row["rmse"] > row["rmse_floor"], (m, r)
            assert row["true_error_ratio"] == pytest.approx(
                row["rmse_vs_true"] / row["sensor_rmse"]
            )
        acc = comp["md-s-l"][r]["accuracy_pct"]
        assert acc == pytest.approx(100 - comp["md-s-l"][r]["mean_rel_err_pct"])


def test_seeds_give_a_spread_and_outputs_are_written(study_run):
    out, results, _, files, _ = study_run
    acc = np.array(results["ablation"]["accuracy"]["md-s-l"])
    assert np.all(acc.std(axis=0) > 0)  # ten seeds, ten different residual models
    saved = json.loads((out / "results.json").read_text())
    assert saved["data"]["hash"] == results["data"]["hash"]
    assert saved["timings"]["stages"]["report"] > 0
    for key in ("report", "results", "predictions"):
        assert files[key].is_file()


def test_rerun_resumes_from_the_cache(study_run):
    out, results, _, _, first = study_run
    assert not any(cached for _, cached in first)
    again = []
    study = Study(TINY, out_dir=out, workers=2, stage=lambda n, t: lambda i, r, c: again.append(c))
    results2, _ = study.run(load_default())
    assert again and all(again)  # nothing was fitted a second time
    assert results2["comparison"]["metrics"] == results["comparison"]["metrics"]


@pytest.mark.parametrize("name", ["quick", "standard", "paper"])
def test_every_plan_builds_valid_models(name):
    """Study plans that are too slow to run here still give valid hyperparameters for every model."""
    from drafttwin.models import make_model
    from drafttwin.models.registry import MODEL_NAMES, get_profile
    from drafttwin.studies.paper.plan import get_study_plan, grid_configs

    plan = get_study_plan(name)
    overrides = {
        k: v for k, v in (("epochs", plan.epochs), ("patience", plan.patience)) if v is not None
    }
    for model in MODEL_NAMES:
        hyper = overrides if model not in ("mechanistic", "persistence") else {}
        make_model(model, plan.model_profile, **hyper)._check_params()
    grid = grid_configs(plan, get_profile(plan.model_profile).window)
    assert len(grid) == 36 and {c["net"] for c in grid} == {"lstm", "gru"}
    for c in grid[:: len(grid) - 1]:
        make_model(c["net"], plan.model_profile, hidden=c["hidden"], layers=c["layers"],
                   lr=c["lr"], epochs=c["epochs"], patience=c["patience"])._check_params()  # fmt: skip
    if name == "paper":
        paper = get_profile("paper")
        assert (
            paper.data_hidden,
            paper.data_layers,
            paper.residual_hidden,
            paper.residual_layers,
        ) == (128, 3, 256, 3)
        assert (paper.batch_size, paper.epochs, paper.lr, paper.dropout) == (10, 500, 1e-3, 0.2)


def test_calibration_stage_compares_nominal_and_calibrated_physics(study_run):
    _, results, _, files, _ = study_run
    cal = results["calibration"]
    assert cal["models"] == ["mechanistic", "parallel", "md-s-l"]
    report = cal["report"]
    assert report["rmse_after"] < report["rmse_before"]  # fitted on the training part
    nominal, calibrated = cal["metrics"]["nominal"], cal["metrics"]["calibrated"]
    assert nominal["parallel"] == results["comparison"]["metrics"]["parallel"]
    for model in cal["models"]:
        assert set(calibrated[model]) == set(ROLLERS)
    # the calibrated physics is another prediction, scored on the same test samples
    for r in ROLLERS:
        assert calibrated["mechanistic"][r]["n_scored"] == nominal["mechanistic"][r]["n_scored"]
        assert calibrated["mechanistic"][r]["rmse"] != nominal["mechanistic"][r]["rmse"]
    assert 'id="calibration"' in files["report"].read_text()


def test_the_quick_plan_keeps_the_residual_lstm_its_tables_were_made_with(tmp_path):
    """The quick profile's residual LSTM has one layer (for fit's time); the paper study's
    quick plan builds its hybrids with the two layers its tables in docs/study.md came from,
    and its data-driven GRU is the profile's."""
    from drafttwin.models import make_model

    study = Study("quick", out_dir=tmp_path)
    data_hyper, res_hyper = study._hyper({})
    assert make_model("parallel", "quick").layers == 1
    for name in ("parallel", "md-s-l", "md-l"):
        assert make_model(name, "quick", **res_hyper).layers == 2
    gru = make_model("md-s-l", "quick", **data_hyper).data_model
    assert (gru.hidden, gru.layers) == (48, 2)
    assert "layers" not in data_hyper
