"""The study cache is checked before use: every kind of file under ``D/cache``, damaged in every
way, is reported by name, discarded and recomputed, with the same final numbers; a moved study
folder reuses its cache; a study folder is locked against a second run; writes are atomic.

One small study is built per module (a 1-point grid of tiny networks on 12 s of data, one
epoch each); each case damages one file in a copy of it and reruns the study in this process.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
from typer.testing import CliRunner

import drafttwin.studies.paper.plan as plan
from drafttwin.cli import app
from drafttwin.datasets import load_default
from drafttwin.execution import integrity
from drafttwin.execution.lock import StudyLocked, study_lock
from drafttwin.studies.paper.plan import STUDY_PLANS
from drafttwin.studies.paper.run import Study

SMALL = replace(STUDY_PLANS["quick"], name="cache-test", data_duration_s=12.0, epochs=1,
                patience=None, grid_epochs=1, grid_train_samples=300, ablation_tests=2,
                use_grid_best=True)  # fmt: skip
SMALL_GRID = {"GRID_LR": (0.01,), "GRID_HIDDEN": (8,), "GRID_LAYERS": (1,)}
"""One grid point per network: the grid's winners size the later networks (8 units)."""

FILE_KINDS: dict[str, Callable[[Path], Path]] = {
    "result-json": lambda c: next(
        p for p in sorted((c / "results").glob("*.json")) if "gru_path" in p.read_text()
    ),  # fmt: skip
    "mechanistic-npy": lambda c: next(c.glob("mechanistic-*.npy")),
    "calibrated-npy": lambda c: next(c.glob("calibrated-*.npy")),
    "calibrated-json": lambda c: next(c.glob("calibrated-*.json")),
    "prepared-npz": lambda c: next(c.glob("data-*.npz")),
    "gru-model": lambda c: next((c / "artifacts").glob("*.gru.dtm")),
    "oof-npy": lambda c: next((c / "artifacts").glob("*.oof.npy")),
    "pred-npy": lambda c: sorted((c / "artifacts").glob("*.pred.npy"))[0],
}


def _flip(data: bytes) -> bytes:
    i = len(data) * 7 // 8  # in an array, a row of the scored test part
    return data[:i] + bytes([data[i] ^ 0xFF]) + data[i + 1 :]


def _tamper(data: bytes) -> bytes:
    """Change one number so the JSON still parses."""
    text = data.decode()
    match = re.search(r'"rmse\w*": (-?\d+\.\d+)', text)  # a result, not the configuration
    assert match, "no number to tamper with"
    changed = str(float(match.group(1)) + 1.0)
    return (text[: match.start(1)] + changed + text[match.end(1) :]).encode()


def _alter_first_digit(sidecar: bytes) -> bytes:
    """Another first hex digit (a fixed one would leave a hash that starts with it unchanged)."""
    return (b"1" if sidecar[:1] == b"0" else b"0") + sidecar[1:]


def _rewrite(transform: Callable[[bytes], bytes]) -> Callable[[Path], None]:
    return lambda p: p.write_bytes(transform(p.read_bytes()))


DAMAGES: dict[str, Callable[[Path], None]] = {
    "truncated-by-one-byte": _rewrite(lambda d: d[:-1]),
    "byte-flipped": _rewrite(_flip),
    "emptied": _rewrite(lambda d: b""),
    "replaced-with-garbage": _rewrite(lambda d: b"not a cache file\n" * 8),
    "number-tampered": _rewrite(_tamper),
    "sidecar-deleted": lambda p: integrity.sidecar(p).unlink(),
    "sidecar-altered": lambda p: _rewrite(_alter_first_digit)(integrity.sidecar(p)),
}
PHYSICS = ("mechanistic-npy", "calibrated-npy", "calibrated-json")
"""Kinds whose recomputation simulates the drive train (seconds each): one rerun per damage
kind damages all three, and each must be reported by name."""


def _applies(kind: str, damage: str) -> bool:
    return damage != "number-tampered" or kind.endswith("-json")


CASES = [(k, d) for k in FILE_KINDS for d in DAMAGES if k not in PHYSICS and _applies(k, d)]


def _numbers(results: dict[str, Any], predictions: pd.DataFrame) -> str:
    """The study's results without timings, and a hash of its predictions: what must not
    change when a cache entry is recomputed (NaN-safe text)."""

    def strip(x: Any) -> Any:
        if isinstance(x, dict):
            return {k: strip(v) for k, v in x.items()
                    if k not in ("wall_s", "timings", "created_utc")}  # fmt: skip
        if isinstance(x, list):
            return [strip(v) for v in x]
        return x

    digest = hashlib.sha256(predictions.to_numpy().tobytes()).hexdigest()
    return json.dumps(strip(results), sort_keys=True, default=str) + digest


def _run(out: Path, cached: list[bool] | None = None) -> str:
    def stage(name: str, total: int) -> Callable[[int, dict, bool], None]:
        return lambda i, r, c: cached.append(c) if cached is not None else None

    return _numbers(*Study(SMALL, out_dir=out, workers=1, stage=stage).run(SERIES))


SERIES = load_default()


@pytest.fixture(scope="module", autouse=True)
def small_grid() -> Iterator[None]:
    with pytest.MonkeyPatch.context() as mp:
        for name, value in SMALL_GRID.items():
            mp.setattr(plan, name, value)
        yield


@pytest.fixture(scope="module")
def pristine(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("pristine") / "D"
    return out, _run(out)


@pytest.fixture
def study(pristine: tuple[Path, str], tmp_path: Path) -> tuple[Path, str]:
    """A fresh copy of the pristine study and its numbers."""
    out = tmp_path / "D"
    shutil.copytree(pristine[0], out)
    return out, pristine[1]


def test_every_cache_file_has_a_sidecar_and_the_study_holds_every_kind(pristine) -> None:
    cache = pristine[0] / "cache"
    files = [p for p in cache.rglob("*") if p.is_file() and p.suffix != ".sha256"]
    assert files and all(integrity.problem(p) is None for p in files)
    for kind, pick in FILE_KINDS.items():
        assert pick(cache).is_file(), kind
    doc = json.loads(FILE_KINDS["result-json"](cache).read_text())
    assert doc["artifacts"] and all(not Path(p).is_absolute() for p in doc["artifacts"])


def _damage_and_rerun(out: Path, expected: str, kinds: list[str], damage: str,
                      capfd: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Damage one file of each kind, rerun: each is reported by name in one line, set aside,
    recomputed, the numbers are the same; a second rerun reuses everything silently."""
    targets = [FILE_KINDS[kind](out / "cache") for kind in kinds]
    for target in targets:
        DAMAGES[damage](target)
    capfd.readouterr()
    assert _run(out) == expected  # recomputed, the same numbers
    err = capfd.readouterr().err
    assert "Traceback" not in err
    reported = [line for line in err.splitlines() if "is damaged" in line]
    assert len(reported) == len(targets), err  # one line per damaged file, naming it
    for target in targets:
        assert [x for x in reported if x.startswith(f"cache entry {target} is damaged (")], err
    for target in targets:
        assert integrity.problem(target) is None  # written again, checked
        if damage != "sidecar-deleted":
            assert target.with_name(target.name + ".damaged").is_file()  # kept for inspection
    cached: list[bool] = []
    assert _run(out, cached) == expected and all(cached)  # and now reused, silently
    assert "damaged" not in capfd.readouterr().err


@pytest.mark.parametrize(("kind", "damage"), CASES, ids=[f"{k}-{d}" for k, d in CASES])
def test_a_damaged_cache_file_is_reported_discarded_and_recomputed(
    study: tuple[Path, str], kind: str, damage: str, capfd: pytest.CaptureFixture[str]
) -> None:
    _damage_and_rerun(*study, [kind], damage, capfd)


@pytest.mark.parametrize("damage", list(DAMAGES))
def test_damaged_physics_caches_are_reported_discarded_and_recomputed(
    study: tuple[Path, str], damage: str, capfd: pytest.CaptureFixture[str]
) -> None:
    kinds = [kind for kind in PHYSICS if _applies(kind, damage)]
    _damage_and_rerun(*study, kinds, damage, capfd)


def test_every_damaged_artifact_of_one_result_is_reported(study, capfd) -> None:
    """The data model's GRU, out-of-fold and predictions all damaged: all three named."""
    _damage_and_rerun(*study, ["gru-model", "oof-npy", "pred-npy"], "truncated-by-one-byte", capfd)


def test_a_result_tampered_and_resealed_is_caught_by_its_self_hash(study, capfd) -> None:
    out, expected = study
    target = FILE_KINDS["result-json"](out / "cache")
    DAMAGES["number-tampered"](target)
    integrity.sidecar(target).write_text(f"{integrity.sha256_file(target)}  {target.name}\n")
    capfd.readouterr()
    assert _run(out) == expected
    assert (
        f"cache entry {target} is damaged (unreadable: ValueError: content"
        in capfd.readouterr().err
    )


def test_a_moved_study_folder_reuses_its_cache(study, tmp_path, capfd) -> None:
    out, expected = study
    moved = tmp_path / "elsewhere" / "D-moved"
    moved.parent.mkdir()
    out.rename(moved)
    capfd.readouterr()
    cached: list[bool] = []
    assert _run(moved, cached) == expected
    assert cached and all(cached)
    assert "damaged" not in capfd.readouterr().err


def _hold_lock(folder: Path) -> subprocess.Popen[str]:
    """A real second process holding the study lock until killed."""
    script = textwrap.dedent(f"""
        import time
        from drafttwin.execution.lock import study_lock
        with study_lock({str(folder)!r}):
            print("held", flush=True)
            time.sleep(120)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
    return proc


@pytest.mark.parametrize("command", ["reproduce", "grid-search"])
def test_a_second_run_on_a_locked_study_folder_exits_2_naming_the_owner(
    tmp_path: Path, command: str
) -> None:
    holder = _hold_lock(tmp_path)
    try:
        res = CliRunner().invoke(app, [command, "--out", str(tmp_path), "--quiet"])
    finally:
        holder.kill()
        holder.wait()
    assert res.exit_code == 2, res.output
    assert res.exception is None or isinstance(res.exception, SystemExit)
    errors = [line for line in res.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and f"pid {holder.pid}" in errors[0], res.output
    assert "in use by another run" in errors[0] and "Traceback" not in res.output
    assert "another --out" in res.output  # the fix


def test_a_stale_lock_of_a_killed_run_is_taken_over_with_a_note(tmp_path, capfd) -> None:
    holder = _hold_lock(tmp_path)
    holder.send_signal(signal.SIGKILL)
    holder.wait()
    (tmp_path / "cache").mkdir()
    unfinished = tmp_path / "cache" / ".mechanistic-x.npy.a1b2c3d4.npy"  # a killed write
    unfinished.write_bytes(b"partial")
    keep = tmp_path / "cache" / ".hidden-user-file"
    keep.write_text("not ours")
    capfd.readouterr()
    with study_lock(tmp_path) as lock:
        assert json.loads(lock.read_text())["pid"] == os.getpid()
        err = capfd.readouterr().err
        assert f"taking over the stale lock {lock} (pid {holder.pid}" in err
        assert "removed 1 unfinished temporary file" in err
        assert not unfinished.exists() and keep.exists()
        assert len(err.strip().splitlines()) == 1
        # a live holder (this process, through another descriptor) refuses a second one
        with pytest.raises(StudyLocked), study_lock(tmp_path):
            pass
    with study_lock(tmp_path):  # released cleanly: no note
        assert capfd.readouterr().err == ""


@pytest.fixture
def full_disk(tmp_path: Path) -> Iterator[Path]:
    """A small tmpfs (root only) to make a real ENOSPC."""
    mnt = tmp_path / "tmpfs"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(mnt)],
                      capture_output=True).returncode != 0:  # fmt: skip
        pytest.skip("mounting a tmpfs needs root")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def test_a_write_that_fails_for_real_leaves_no_temporary_or_partial_file(
    pristine, full_disk: Path, capfd
) -> None:
    out = full_disk / "D"
    shutil.copytree(pristine[0], out)
    target = FILE_KINDS["mechanistic-npy"](out / "cache")
    DAMAGES["truncated-by-one-byte"](target)
    filler = full_disk / "filler"
    with filler.open("wb", buffering=0) as f:  # fill the disk: nothing more can be written
        try:
            while True:
                f.write(b"\0" * 4096)
        except OSError:
            pass
    before = time.time()
    with pytest.raises(OSError):
        _run(out)
    leftovers = [p for p in out.rglob(".*") if p.stat().st_mtime >= before - 1]
    assert leftovers == []  # no temporary file beside any target
    assert not target.exists()  # the damaged entry is aside, no partial one in its place
    filler.unlink()
    capfd.readouterr()
    assert _run(out) == pristine[1]
    assert not list(out.rglob(".*"))
