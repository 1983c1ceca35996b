"""The executor: local and Ray give the same results; interrupted sweeps resume."""

import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from drafttwin.errors import DrafttwinError
from drafttwin.execution import ResultStore, data_hash, run_tasks, task_key

from ._tasks import slow_marked_task, supply_sweep_point

SWEEP = [{"hz": hz} for hz in (40.0, 44.0, 48.47)]


def test_local_pool_and_serial_agree_and_physics_holds(tmp_path):
    serial = run_tasks(supply_sweep_point, SWEEP, workers=1)
    pooled = run_tasks(supply_sweep_point, SWEEP, workers=2)
    assert serial == pooled
    speeds = [r["front_rpm"] for r in serial]
    assert speeds == sorted(speeds)  # a higher set-point runs faster
    assert speeds[0] / speeds[2] == pytest.approx(40.0 / 48.47, rel=2e-3)


def test_ray_local_instance_gives_same_results_as_local(tmp_path):
    pytest.importorskip("ray")
    local = run_tasks(supply_sweep_point, SWEEP, workers=1)
    ray_results = run_tasks(supply_sweep_point, SWEEP, executor="ray", workers=2)
    assert ray_results == local


def test_store_skips_finished_tasks(tmp_path):
    store = ResultStore(tmp_path / "store")
    markers = tmp_path / "markers"
    markers.mkdir()
    configs = [{"k": k, "marker_dir": str(markers)} for k in range(4)]
    first = run_tasks(slow_marked_task, configs[:2], store=store, data_digest="d", workers=1)
    seen = []
    again = run_tasks(slow_marked_task, configs, store=store, data_digest="d", workers=1,
                      on_result=lambda i, r, cached: seen.append((i, cached)))  # fmt: skip
    assert again[:2] == first and [r["square"] for r in again] == [0, 1, 4, 9]
    assert sorted(seen) == [(0, True), (1, True), (2, False), (3, False)]
    assert len(list(markers.iterdir())) == 4  # every configuration ran exactly once
    # another data set is another task
    assert task_key(configs[0], "d") != task_key(configs[0], data_hash(__import__("numpy").ones(3)))


def test_results_of_other_code_are_not_read_back(tmp_path, monkeypatch):
    """A result cached by another version of the code is recomputed, not trusted: the task
    key holds a fingerprint of the package's sources."""
    from drafttwin.execution import store as store_module

    fingerprint = store_module.code_fingerprint()
    assert len(fingerprint) == 64 and fingerprint == store_module.code_fingerprint()
    store = ResultStore(tmp_path / "store")
    markers = tmp_path / "markers"
    markers.mkdir()
    config = [{"k": 3, "marker_dir": str(markers)}]
    key_before = task_key(config[0], "d")
    run_tasks(slow_marked_task, config, store=store, data_digest="d", workers=1)
    monkeypatch.setattr(store_module, "code_fingerprint", lambda: "0" * 64)  # the code changed
    assert task_key(config[0], "d") != key_before
    seen = []
    run_tasks(slow_marked_task, config, store=store, data_digest="d", workers=1,
              on_result=lambda i, r, cached: seen.append(cached))  # fmt: skip
    assert seen == [False]  # computed again


def test_killed_sweep_resumes_without_repeating(tmp_path):
    store_dir, markers = tmp_path / "store", tmp_path / "markers"
    markers.mkdir()
    script = textwrap.dedent(f"""
        from drafttwin.execution import ResultStore, run_tasks
        from tests._tasks import slow_marked_task
        configs = [{{"k": k, "marker_dir": {str(markers)!r}, "sleep": 0.3}} for k in range(8)]
        run_tasks(slow_marked_task, configs, store=ResultStore({str(store_dir)!r}), workers=1)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=Path(__file__).resolve().parents[1])
    store = ResultStore(store_dir)
    deadline = time.time() + 60
    while len(store) < 3 and time.time() < deadline:
        time.sleep(0.05)
    proc.kill()
    proc.wait()
    finished = len(store)
    assert 3 <= finished < 8
    started_before = {p.name.split("-")[1] for p in markers.iterdir()}
    for p in markers.iterdir():
        p.unlink()
    configs = [{"k": k, "marker_dir": str(markers), "sleep": 0.3} for k in range(8)]
    results = run_tasks(slow_marked_task, configs, store=store, workers=1)
    assert [r["square"] for r in results] == [k * k for k in range(8)]
    rerun = {int(p.name.split("-")[1]) for p in markers.iterdir()}
    assert len(rerun) == 8 - finished  # finished configurations were not repeated
    assert len(started_before) >= finished


def test_unknown_executor_refused():
    with pytest.raises(DrafttwinError, match="unknown executor"):
        run_tasks(slow_marked_task, [{"k": 1, "marker_dir": "."}], executor="dask")
