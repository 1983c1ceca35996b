"""The generalisation benchmark (issue 16): its records, floor, hybrid structures and the
quick run through the command line."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from drafttwin._constants import ROLLERS
from drafttwin.cli import app
from drafttwin.evaluation.limits import LAG1_PREMISE
from drafttwin.mechanics import kinematics
from drafttwin.models import make_model
from drafttwin.models.estimators.hybrid import FADE_WIDTH
from drafttwin.studies.generalisation import records as R
from drafttwin.studies.generalisation.plan import MODELS, TASKS

from ..._synthetic import TINY, make_series, mechanistic, one_thread

runner = CliRunner()


# ---- the records ----------------------------------------------------------------------------
def test_draft_gears_change_the_drafts_and_the_plant_follows() -> None:
    changed = kinematics(R.nominal_train(draft_gears=True)).drafts
    nominal = kinematics(R.nominal_train()).drafts
    assert changed["total"] == pytest.approx(nominal["total"] * 52 / 49)
    assert changed["break"] == pytest.approx(nominal["break"] * 30 / 28)
    series = R.make_record(R.TEST_RECORDS["draft-gears"], 2.0, 100.0)
    assert series.truth is not None
    mean = np.mean(series.truth[50:], axis=0)
    assert mean[0] / mean[3] == pytest.approx(changed["total"] * 35 / 45, rel=0.01)


def test_speed_records_scale_the_set_point_and_stop_comes_to_rest() -> None:
    base = R.make_record(R.TEST_RECORDS["little-data"], 2.0, 100.0)
    fast = R.make_record(R.TEST_RECORDS["speed+25"], 2.0, 100.0)
    assert np.mean(fast.inputs["supply_hz"]) == pytest.approx(
        1.25 * np.mean(base.inputs["supply_hz"])
    )
    assert base.truth is not None and fast.truth is not None
    ratio = np.mean(fast.truth, axis=0) / np.mean(base.truth, axis=0)
    assert ratio == pytest.approx(np.full(4, 1.25), rel=0.01)
    stop = R.make_record(R.TEST_RECORDS["stop"], 20.0, 100.0)  # ramp 10-18 s, then at rest
    assert stop.truth is not None
    assert np.abs(stop.truth[-50:]).max() < 1.0  # rpm: at rest after the ramp


# ---- hybrid structure -----------------------------------------------------------------------
def _shifted(series, rpm: float):
    return series.with_values(series.values + rpm)


@pytest.mark.parametrize("name", ["parallel", "md-s-l"])
def test_faded_hybrid_falls_back_on_its_physics_far_outside_training(
    name: str, tmp_path: Path
) -> None:
    """Far outside the training range (measured speeds 1000 rpm off the physics) the faded
    correction is nothing: the hybrid predicts its physics exactly; inside it the correction
    is kept."""
    from drafttwin.models import load_model
    from drafttwin.models.estimators.base import BaseModel

    series, _ = make_series(400, seed=2)
    extra = {"folds": 2, "data_window": 8, "data_hidden": 8, "data_layers": 1,
             "sk_channels": 6} if name == "md-s-l" else {}  # fmt: skip
    with one_thread():
        model = make_model(name, "quick", **TINY, **extra, structure="relative", fade=True)
        model.fit(series, mechanistic)
        far = _shifted(series, 1000.0)
        far_mech = mechanistic(far.time_s)
        pred = model.predict_values(far, far_mech)
        ok = np.isfinite(pred).all(axis=1)
        assert ok.sum() > 100
        np.testing.assert_allclose(pred[ok], far_mech[ok], rtol=0, atol=1e-9)
        near = model.predict_values(series, mechanistic(series.time_s))
        assert np.nanmax(np.abs(near - mechanistic(series.time_s))) > 1e-6
        path = model.save(tmp_path / "m.pt")
        again: BaseModel = load_model(path)
        assert again.get_params()["structure"] == "relative"
        np.testing.assert_allclose(again.predict_values(far, far_mech), pred, equal_nan=True)
    assert FADE_WIDTH > 0


def test_strict_fade_turns_the_correction_off_where_a_held_set_point_moves(
    tmp_path: Path,
) -> None:
    """Trained at one set-point (an input constant in training), the strict fade keeps the
    correction where the set-point holds that value, turns it off on exactly the rows whose
    window saw it move, and survives a save and load; the plain fade ignores the set-point."""
    from drafttwin.models import load_model

    series, _ = make_series(400, seed=4)
    held = np.full(len(series), 48.5)
    train = replace(series, inputs={"supply_hz": held})
    window = TINY["window"]
    with one_thread():
        model = make_model("parallel", "quick", **TINY, inputs=("supply_hz",), fade="strict")
        model.fit(train, mechanistic)
        moved = held.copy()
        moved[200:] = 43.6  # the VFD set-point lowered at row 200
        test = replace(series, inputs={"supply_hz": moved})
        mech = mechanistic(series.time_s)
        strict = model.predict_values(test, mech)
        correction = np.abs(strict - mech).max(axis=1)
        assert np.nanmin(correction[window + 2 : 195]) > 1e-9  # kept before the change
        # off from the first target whose window (rows T-W .. T-1, one step ahead) saw it move
        np.testing.assert_allclose(strict[201:], mech[201:], rtol=0, atol=1e-12)
        np.testing.assert_allclose(strict[:195], model.predict_values(train, mech)[:195])
        model.set_params(fade=True)
        plain = model.predict_values(test, mech)
        assert np.nanmax(np.abs(plain[200:] - mech[200:])) > 1e-9
        model.set_params(fade="strict")
        again = load_model(model.save(tmp_path / "strict.pt"))
        assert again.get_params()["fade"] == "strict"
        np.testing.assert_allclose(again.predict_values(test, mech), strict, equal_nan=True)


def test_model_file_without_the_structure_params_reads_as_absolute(tmp_path: Path) -> None:
    """Files written before ``structure``/``fade`` existed load with the old behaviour."""
    import torch

    from drafttwin.models import load_model
    from drafttwin.models.storage.modelfile import checksum

    series, _ = make_series(300, seed=3)
    with one_thread():
        model = make_model("parallel", "quick", **TINY).fit(series, mechanistic)
        path = model.save(tmp_path / "p.pt")
        payload = torch.load(path, weights_only=True)
        params = json.loads(payload["params_json"])
        del params["structure"], params["fade"]
        payload["params_json"] = json.dumps(params)
        payload["checksum"] = checksum(payload)  # as an older drafttwin wrote it
        old = tmp_path / "old.pt"
        torch.save(payload, old)
        loaded = load_model(old)
        assert (loaded.structure, loaded.fade) == ("absolute", False)
        np.testing.assert_allclose(loaded.predict_values(series, mechanistic),
                                   model.predict_values(series, mechanistic), equal_nan=True)  # fmt: skip


def test_unknown_structure_is_refused() -> None:
    from drafttwin.errors import ConfigError

    with pytest.raises(ConfigError, match="structure"):
        make_model("parallel", "quick", structure="sideways")._check_params()


# ---- the quick benchmark through the command line ------------------------------------------
@pytest.fixture(scope="module")
def quick_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, Path]:
    out = tmp_path_factory.mktemp("gen")
    res = runner.invoke(app, ["benchmark", "generalisation", "--quick", "--json", "--out",
                              str(out), "--no-cache"])  # fmt: skip
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout), out


def test_quick_benchmark_rows_cover_every_scenario_task_and_model(quick_run) -> None:
    doc, out = quick_run
    keys = {(r["scenario"], r["task"], r["model"]) for r in doc["rows"]}
    for scenario in R.SCENARIOS:
        for task in TASKS:
            for model in MODELS:
                assert (scenario, task, model) in keys, (scenario, task, model)
    fields = {"scenario", "task", "model", "train_s", "seed", "channel", "rmse"}
    assert all(fields <= set(r) for r in doc["rows"])
    assert {r["channel"] for r in doc["rows"]} == set(ROLLERS)
    cal = [r for r in doc["rows"] if r["physics"] == "calibrated"]
    assert {r["scenario"] for r in cal} == {"other-machine"}
    lengths = {r["train_s"] for r in doc["rows"] if r["scenario"] == "little-data"
               and r["model"] == "gru"}  # fmt: skip
    assert len(lengths) >= 2
    assert (out / "generalisation_report.html").read_text().count("data:image/png") == 2
    assert json.loads((out / "generalisation_results.json").read_text())["rows"] == doc["rows"]


def test_quick_benchmark_values_are_finite_and_sane(quick_run) -> None:
    doc, _ = quick_run
    for r in doc["rows"]:
        assert r["rmse"] is not None and math.isfinite(r["rmse"]) and r["rmse"] > 0, r
    # the physics follows every set-point and gear set: a few rpm at most, anywhere
    phys = [r["rmse"] for r in doc["rows"] if r["model"] == "mechanistic"]
    assert max(phys) < 10.0
    # one-step persistence errs by the sensor noise and the speed's own change per sample
    pers = [r["rmse"] for r in doc["rows"] if r["model"] == "persistence"
            and r["task"] == "prediction"]  # fmt: skip
    assert max(pers) < 10.0
    for f in doc["floors"]:
        if f["floor"] is None:
            # the oracle refuses only where its counting premise (lag-1 -1/2) fails
            lo, hi = LAG1_PREMISE
            assert not lo <= f["sensor_error_lag1"] <= hi, f
        else:
            assert lo_ok(f["sensor_error_lag1"]), f
            assert 0 < f["floor"] < f["best_rmse"], f  # nothing scores below a floor
        assert f["below_floor"] == [], f
    assert sum(f["floor"] is not None for f in doc["floors"]) >= 2, doc["floors"]
    chosen = {(c["model"], c["task"]) for c in doc["structure_choice"]}
    assert chosen == {(m, t) for m in ("parallel", "md-s-l") for t in TASKS}
    assert {c["scenario"] for c in doc["checks"]} == {"draft-gears", "speed+25", "speed-25"}


def test_structure_choice_takes_the_best_candidate_and_keeps_the_simplest_on_a_tie() -> None:
    from drafttwin.studies.generalisation.run import choose_structures

    rows = [{"model": "mechanistic", "task": "prediction", "scenario": "v", "channel": c,
             "rmse": 1.0} for c in ("a", "b")]  # fmt: skip

    def cand(structure, fade, skip, rmse):
        return [{"model": "parallel", "task": "prediction", "scenario": "v", "channel": c,
                 "rmse": rmse, "structure": structure, "fade": fade, "skip": skip}
                for c in ("a", "b")]  # fmt: skip

    for structure in ("absolute", "relative"):
        for fade in (False, True, "strict"):
            rows += cand(structure, fade, None, 1.0)  # all equal to the physics: a tie
            rows += cand(structure, fade, False, 1.0)
    chosen = choose_structures(rows)[("parallel", "prediction")]
    assert (chosen["structure"], chosen["fade"], chosen["skip"]) == ("absolute", False, None)
    assert len(chosen["scores"]) == 12
    better = [r for r in rows if not (r.get("structure") == "relative"
              and r.get("fade") == "strict" and r.get("skip") is False)]  # fmt: skip
    better += cand("relative", "strict", False, 0.8)
    chosen = choose_structures(better)[("parallel", "prediction")]
    assert (chosen["structure"], chosen["fade"], chosen["skip"]) == ("relative", "strict", False)
    score = {(s["structure"], s["fade"], s["skip"]): s["score"] for s in chosen["scores"]}
    assert score[("relative", "strict", False)] == pytest.approx(0.8)


def test_bad_seeds_option_is_a_one_line_error() -> None:
    res = runner.invoke(app, ["benchmark", "generalisation", "--quick", "--seeds", "0"])
    assert res.exit_code == 2
    assert "Traceback" not in res.output


def test_study_report_section_from_the_quick_run(quick_run) -> None:
    from drafttwin.report.generalisation import physics_pays_section, study_summary

    doc, _ = quick_run
    summary = study_summary(doc)
    assert "rows" not in summary  # the study keeps the summaries only
    text = physics_pays_section({"generalisation": json.loads(json.dumps(summary))})
    assert text.startswith('<section id="generalisation">')
    assert all(s in text for s in R.SCENARIOS)
    assert physics_pays_section({}) == ""


def test_the_results_json_gives_the_markdown_tables_and_the_figures_file(quick_run) -> None:
    """``python -m drafttwin.report.generalisation_results`` (was benchmarks/): the markdown
    it writes where told, the figures below the folder it runs from, nothing else touched."""
    import subprocess
    import sys

    _, out = quick_run
    md = out / "results.md"
    res = subprocess.run([sys.executable, "-m", "drafttwin.report.generalisation_results",
                          str(out / "generalisation_results.json"), "--markdown", str(md)],
                         cwd=out, capture_output=True, text=True, timeout=120)  # fmt: skip
    assert res.returncode == 0, res.stderr
    text = md.read_text()
    for heading in ("## Extrapolation table: free-run simulation", "## Learning curves",
                    "## One-step floor (oracle)", "## Hybrid RMSE / GRU RMSE"):  # fmt: skip
        assert heading in text
    figures = json.loads((out / "benchmarks" / "results" / "generalisation.json").read_text())
    assert figures["benchmark"] == "generalisation" and figures["figures"]
    assert all(f["unit"] in ("rpm", "s") for f in figures["figures"])


def lo_ok(lag1: float) -> bool:
    """Whether a lag-1 autocorrelation lies within the floor oracle's premise."""
    return LAG1_PREMISE[0] <= lag1 <= LAG1_PREMISE[1]


def test_the_floor_table_reads_a_channel_without_a_floor() -> None:
    """The oracle gives no floor where a channel's encoder errors lack the counting premise
    (None in the JSON): the table says so instead of failing (TypeError before)."""
    from drafttwin.report.generalisation import floor_rows

    floors = [
        {"channel": "front", "floor": 0.21, "best_rmse": 0.25, "best_model": "gru"},
        {"channel": "second", "floor": None, "best_rmse": 0.3, "best_model": "parallel"},
        {"channel": "third", "floor": 0.2, "best_rmse": 0.1, "best_model": "gru"},
        {"channel": "back", "floor": 0.2, "best_rmse": None, "best_model": None},
    ]
    _, rows = floor_rows({"floors": floors})
    assert [r[-1] for r in rows] == ["no", "no floor", "YES (the floor is wrong)", "no run"]
    assert rows[1][1] == "n/a"
    floors[1]["sensor_error_lag1"] = -0.213
    _, rows = floor_rows({"floors": floors})
    assert rows[1][-1] == (
        "no floor (sensor errors' lag-1 autocorrelation -0.21, not a counting encoder's -0.5)"
    )


def test_learning_curves_of_equal_seeds_draw_without_negative_error_bars() -> None:
    """Three seeds that score alike (a hybrid keeping no correction equals its physics on
    every seed): the float mean of 3 x 0.7 lies 1.1e-16 below 0.7, which made the full run's
    report fail in matplotlib ("'yerr' must not contain negative values")."""
    from drafttwin.report.generalisation import learning_png
    from drafttwin.studies.generalisation.summary import learning_curves

    rows = [{"scenario": "little-data", "task": task, "model": "parallel", "train_s": 10.0,
             "seed": seed, "channel": channel, "rmse": 0.7}
            for task in TASKS for channel in ROLLERS for seed in range(3)]  # fmt: skip
    curves = learning_curves(rows)
    for c in curves:
        assert c["rmse"]["min"] <= c["rmse"]["mean"] <= c["rmse"]["max"]
        assert c["rmse"]["std"] == 0.0
    assert learning_png({"learning_curves": curves})[:4] == b"\x89PNG"


def test_sensor_error_lag1_is_measured_on_the_scored_rows(tmp_path: Path) -> None:
    """A counting encoder's error (a quantisation error's difference: lag-one
    autocorrelation -1/2) with a few spikes the paper's outlier rule flags: the figure the
    floor table prints must be the scored rows' -1/2 (with the spikes it read -0.008 on the
    full run's second roller, beside a floor that was computed without them)."""
    from drafttwin.data.series import MeasurementSeries
    from drafttwin.studies.generalisation.fits import INPUT, save_records
    from drafttwin.studies.generalisation.run import _sensor_error_lag1

    rng = np.random.default_rng(0)
    n = 4000
    truth = np.full((n, len(ROLLERS)), 100.0) + rng.normal(0, 2.0, (n, 1)).cumsum(0) * 0.01
    q = rng.uniform(-0.5, 0.5, (n + 1, len(ROLLERS)))
    values = truth + (q[1:] - q[:-1])
    values[rng.choice(n - 2, 12, replace=False) + 1] += 40.0  # spikes: 40 % jumps
    series = MeasurementSeries(np.arange(n) / 100.0, values, ROLLERS,
                               inputs={INPUT: np.full(n, 50.0)}, truth=truth)  # fmt: skip
    path = tmp_path / "records.npz"
    save_records(path, {"little-data": series}, {})
    raw = values - truth
    raw_lag1 = [float(np.corrcoef(raw[:-1, j], raw[1:, j])[0, 1]) for j in range(len(ROLLERS))]
    assert all(abs(r) < 0.2 for r in raw_lag1)  # the spikes hide the premise in the raw errors
    for channel, rho in _sensor_error_lag1(path, "little-data").items():
        assert -0.6 <= rho <= -0.4, (channel, rho)
