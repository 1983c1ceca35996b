"""The fault benchmark on a tiny plan: plan, scores, page, CLI refusals."""

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from drafttwin.cli import app
from drafttwin.plant.faults import KINDS, SURFACE_ONLY
from drafttwin.studies.faults.plan import (
    ELEMENTS,
    PLANS,
    BenchmarkPlan,
    decided_s,
    task_configs,
    with_healthy_hours,
)
from drafttwin.studies.faults.score import by_kind, poisson_upper


def test_full_plan_covers_every_kind_three_severities_both_profiles():
    tasks = task_configs(PLANS["full"], seed=0)
    faults = [t for t in tasks if t["set"] == "faults"]
    encoders_see = set(KINDS) - set(SURFACE_ONLY)  # a flute moves no speed: the sliver's
    assert set(ELEMENTS) == encoders_see
    assert len(faults) >= 60
    seen = {(t["faults"][0]["kind"], t["level"], t["profile"]) for t in faults}
    assert seen == {(k, lv, p) for k in encoders_see for lv in range(3) for p in ("step", "ramp")}
    machines = [t["machine_seed"] for t in tasks]
    assert len(set(machines)) == len(machines)  # tuning, faults and healthy share no machine
    assert task_configs(PLANS["full"], seed=0) == tasks  # seeded


def test_full_plan_has_two_hours_of_watched_healthy_running_on_several_machines():
    healthy = [t for t in task_configs(PLANS["full"], seed=0) if t["set"] == "healthy"]
    assert len(healthy) >= 5
    assert sum(decided_s(t["duration_s"]) for t in healthy) >= 2 * 3600  # issue 13
    assert decided_s(PLANS["full"].healthy[1]) == PLANS["full"].healthy[1] - 15.0
    more = with_healthy_hours(PLANS["full"], 72.0)
    assert more.healthy[0] * decided_s(more.healthy[1]) >= 72 * 3600
    assert (more.healthy[0] - 1) * decided_s(more.healthy[1]) < 72 * 3600  # no more than needed


def test_poisson_bound_is_the_rule_of_three():
    assert poisson_upper(0, 72.0) == pytest.approx(3.0 / 72 * 24, rel=0.01)  # ~1 per 24 h


@pytest.mark.slow
def test_tiny_benchmark_scores_and_page():
    from drafttwin.report.faults_bench import render_benchmark
    from drafttwin.studies.faults import run_benchmark

    tiny = BenchmarkPlan("tiny", ("belt_wear", "gain"), (2,), ("step",), 24.0, (17.0, 17.5), 5.0,
                   (1, 30.0), (1, 20.0))  # fmt: skip
    res = run_benchmark(tiny, seed=3, workers=1)
    phys, raw = res["scores"]["physics"], res["scores"]["raw-threshold"]
    assert res["sets"] == {"tuning": 1, "faults": 2, "healthy": 1}
    assert phys["detection_pct"]["severe"] == 100.0  # belt -0.8 and a 2 % gain: plain to see
    assert phys["localisation"]["top1_pct"] == 100.0
    assert phys["localisation"]["sensor_blamed_on_machine"] == 0
    assert phys["confusion"] == {"belt_wear": {"belt_wear": 1}, "gain": {"gain": 1}}
    cell = phys["by_kind"]["gain"]["severe"]
    assert (cell["records"], cell["detected"], cell["top1"], cell["group_hit"]) == (1, 1, 1, 1)
    assert raw["localisation"] is None  # the baseline does not locate
    hyb, dd = res["scores"]["hybrid"], res["scores"]["data-driven"]
    assert hyb["detection_pct"]["severe"] == 100.0  # open loop: the hybrid sees the shift too
    assert hyb["localisation"]["top1_pct"] == 100.0  # and the physics ranking names it
    assert hyb["localisation"]["sensor_blamed_on_machine"] == 0
    assert dd["localisation"] is None  # a one-step innovation is not localised
    assert set(res["detectors"]) == {"physics", "hybrid", "data-driven"}
    assert res["learned"]["data-driven"]["task"] == "prediction"
    json.dumps(res, allow_nan=True)
    html = render_benchmark(res)
    assert 'id="scores"' in html and 'id="confusion"' in html and "raw-threshold" in html
    assert 'id="confusion-hybrid"' in html and "data-driven" in html
    # the page says what the hybrid's folds kept (its column is the physics' when nothing)
    assert res["learned"]["hybrid"]["correction"]["kept"] in {"level", "offset", "none"}
    assert "its validation folds kept" in html


def test_the_page_says_a_hybrid_that_kept_nothing_is_the_physics():
    from drafttwin.report.faults_bench import _learned_note

    fit = {"model": "ParallelHybrid", "task": "simulation", "fit_s": 2.6, "epochs": 10,
           "val_loss": 0.0025}  # fmt: skip
    learned = {"window": 10, "hidden": 16, "layers": 1,
               "hybrid": {**fit, "correction": {"kept": "none",
                                                 "chosen_fold_nrmse": [1.0006, 1.0054]}}}  # fmt: skip
    note = _learned_note(learned)
    assert "kept no correction: it predicts the physics itself" in note
    assert "fold NRMSE 1.001, 1.005" in note
    older = _learned_note({**learned, "hybrid": fit})  # results written before it was kept
    assert "validation folds" not in older and older.endswith("set-points only.")


def test_by_kind_counts_every_record_and_places_only_detected_ones():
    rows = [
        {"kind": "wear", "level": 1, "profile": "step", "detected": True, "delay_s": 1.5,
         "top1": False, "group_hit": True},
        {"kind": "wear", "level": 1, "profile": "ramp", "detected": False, "delay_s": None},
        {"name": "healthy_0", "set": "healthy", "healthy_s": 615.0, "false_alarms": 0},
    ]  # fmt: skip
    assert by_kind(rows) == {"wear": {"moderate": {
        "records": 2, "detected": 1, "top1": 0, "group_hit": 1,
        "delay_s": {"step": 1.5, "ramp": None}}}}  # fmt: skip


def test_cli_refuses_bad_numbers(tmp_path):
    res = CliRunner().invoke(app, ["benchmark", "faults", "--workers", "0", "--out", str(tmp_path)])
    assert res.exit_code == 2 and "--workers" in res.output


def test_the_sliver_variant_names_what_each_healthy_chimney_is_put_down_to() -> None:
    """A healthy record's chimney is listed with its first candidate, or as the feed's (the
    printout called every one 'their own gears' lines' before, a feed excursion too)."""
    from drafttwin.studies.faults.sliver import score

    feed = {"wavelength_m": 0.9888, "candidates": []}
    gear = {"wavelength_m": 0.1414, "candidates": ["gear B (A-B)", "roller front"]}
    rows = [{"set": "healthy", "sliver_m": 128.0, "causes": [feed], "new_causes": [feed]},
            {"set": "healthy", "sliver_m": 128.0, "causes": [gear], "new_causes": []},
            {"set": "healthy", "sliver_m": 128.0, "causes": [], "new_causes": []}]  # fmt: skip
    s = score(rows)
    assert s["healthy_lines"] == [{"wavelength_m": 0.9888, "cause": "from the feed"},
                                  {"wavelength_m": 0.1414, "cause": "gear B (A-B)"}]  # fmt: skip
    assert (s["healthy_chimneys"], s["healthy_records_with_chimney"]) == (2, 2)
    assert s["healthy_chimneys_per_100m"] == pytest.approx(2 / 384 * 100)
    assert s["healthy_new_chimneys"] == 1


def test_options_a_variant_would_ignore_are_refused(tmp_path):
    """--live with --sliver, --records with --sliver, --speed without --live: each ran the
    other variant without a word."""
    for extra, named in ((["--live", "--sliver"], "--live: not used by --sliver"),
                         (["--sliver", "--records", str(tmp_path / "r")], "--records"),
                         (["--speed", "8"], "not used by the offline benchmark")):  # fmt: skip
        res = CliRunner().invoke(app, ["benchmark", "faults", "--quick", *extra, "--out",
                                       str(tmp_path / "out")])  # fmt: skip
        assert res.exit_code == 2 and named in res.output, res.output
    assert not (tmp_path / "out").exists() and not (tmp_path / "r").exists()


@pytest.mark.slow
def test_sigterm_stops_the_offline_benchmark_in_one_line(tmp_path):
    """It died at once with exit 143 and no word, its two workers still running 2 s later."""
    import signal
    import subprocess
    import sys
    import time

    proc = subprocess.Popen([sys.executable, "-m", "drafttwin", "benchmark", "faults", "--quick",
                             "--quiet", "--out", str(tmp_path / "fb")], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    deadline = time.monotonic() + 60.0  # into the records, the workers busy
    while not (children := _children(proc.pid)) and time.monotonic() < deadline:
        time.sleep(0.5)
    assert children  # the workers
    time.sleep(2.0)
    start = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    assert time.monotonic() - start < 5
    assert proc.returncode == 143 and "Traceback" not in err, err
    assert "interrupted by SIGTERM" in err.splitlines()[0], err
    assert not (tmp_path / "fb" / "faults_results.json").exists()
    time.sleep(3.0)
    alive = [pid for pid in children if Path(f"/proc/{pid}").exists()
             and Path(f"/proc/{pid}/stat").read_text().split(") ")[-1][0] != "Z"]  # fmt: skip
    assert not alive, alive


def _children(pid: int) -> list[int]:
    """The process ids whose parent is ``pid`` (Linux /proc)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(") ", 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out
