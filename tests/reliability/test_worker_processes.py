"""A study's worker processes end with it: real runs of the CLI, real signals, /proc checked.

``grid-search`` with a tiny budget (``_tiny_study.py``: the real command line, a small grid)
is started with two workers and signalled once its workers exist: SIGKILL (the parent cannot
clean up: the workers notice and exit), SIGTERM, Ctrl-C to the parent and to the whole process
group as a terminal sends it, once and twice. Every descendant recorded before the signal must
be gone within 10 s, TERM/INT must exit 143/130 with one line, and a rerun must give the same
numbers as an uninterrupted run. The same for a private Ray instance (slow: Ray starts in
seconds). Bad ``--executor``/``--workers``/``--address`` values are refused with one line and
exit 2 before any data are read or prepared.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from drafttwin.cli import app

TINY = Path(__file__).with_name("_tiny_study.py")
GONE_WITHIN_S = 10.0
START_TIMEOUT_S = 120.0


# ---- processes, read from /proc -------------------------------------------------------------
def _stat(pid: int) -> list[str] | None:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return None if fields[0] in ("Z", "X") else fields


def _descendants(pid: int) -> dict[int, str]:
    """Live descendants of ``pid``: pid -> start time (so a reused pid is not mistaken)."""
    kids: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and (st := _stat(int(entry.name))) is not None:
            kids.setdefault(int(st[1]), []).append(int(entry.name))
    found: dict[int, str] = {}
    todo = [pid]
    while todo:
        for child in kids.get(todo.pop(), []):
            if (st := _stat(child)) is not None:
                found[child] = st[19]
                todo.append(child)
    return found


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _alive(procs: dict[int, str]) -> dict[int, str]:
    return {p: t for p, t in procs.items() if (st := _stat(p)) is not None and st[19] == t}


def _kill_all(procs: dict[int, str]) -> None:
    for pid in _alive(procs):
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGKILL)


# ---- the study ------------------------------------------------------------------------------
def _command(out: Path, *extra: str) -> list[str]:
    return [sys.executable, str(TINY), "grid-search", "--profile", "tiny", "--workers", "2",
            "--quiet", "--out", str(out), *extra]  # fmt: skip


def _numbers(out: Path) -> Any:
    """grid.json without the wall-clock times."""

    def strip(x: Any) -> Any:
        if isinstance(x, dict):
            return {k: strip(v) for k, v in x.items() if k != "wall_s"}
        if isinstance(x, list):
            return [strip(v) for v in x]
        return x

    return strip(json.loads((out / "grid.json").read_text()))


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> tuple[Any, Path]:
    """An uninterrupted run's numbers, and a study folder with the data prepared only."""
    out = tmp_path_factory.mktemp("reference")
    subprocess.run(_command(out), check=True, timeout=600, stdout=subprocess.DEVNULL)
    prepared = tmp_path_factory.mktemp("prepared") / "study"
    shutil.copytree(out, prepared, ignore=shutil.ignore_patterns("results", "grid.json"))
    return _numbers(out), prepared


def _start(prepared: Path, out: Path, *extra: str) -> tuple[subprocess.Popen, Path]:
    shutil.copytree(prepared, out)
    err = out.with_suffix(".stderr")
    proc = subprocess.Popen(_command(out, *extra), stdout=subprocess.DEVNULL,
                            stderr=err.open("w"), start_new_session=True)  # fmt: skip
    return proc, err


def _wait_for_workers(proc: subprocess.Popen, marker: str, count: int) -> dict[int, str]:
    """The parent's descendants once ``count`` of them have ``marker`` in their command line."""
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        procs = _descendants(proc.pid)
        if sum(marker in _cmdline(p) for p in procs) >= count:
            return procs
        assert proc.poll() is None, "the study ended before its workers started"
        time.sleep(0.05)
    raise AssertionError(f"no {count} workers ({marker}) within {START_TIMEOUT_S} s")


def _signal(proc: subprocess.Popen, how: str) -> None:
    """``how``: a signal name, 'group:' + name (to the process group, as a terminal does),
    twice with ' x2'."""
    name, _, times = how.partition(" x")
    group = name.startswith("group:")
    signum = getattr(signal, name.removeprefix("group:"))
    for k in range(int(times or 1)):
        if k:
            time.sleep(0.3)
        if proc.poll() is None:
            (os.killpg if group else os.kill)(proc.pid, signum)


def _interrupt(proc: subprocess.Popen, how: str, procs: dict[int, str]) -> tuple[int, float]:
    """Signal the parent; its exit code and how long its descendants outlived it."""
    try:
        _signal(proc, how)
        rc = proc.wait(timeout=30)
        t0 = time.monotonic()
        while _alive(procs) and time.monotonic() - t0 < GONE_WITHIN_S + 5:
            time.sleep(0.05)
        return rc, time.monotonic() - t0
    finally:
        _kill_all({proc.pid: _stat(proc.pid)[19]} if _stat(proc.pid) else {})
        left = _alive(procs)
        _kill_all(procs)
        assert not left, f"left running: {[(p, _cmdline(p)[:80]) for p in left]}"


EXIT = {"SIGKILL": -9, "SIGTERM": 143, "SIGINT": 130}


def _assert_exit(how: str, rc: int, err: Path) -> None:
    name = how.split(" ")[0].removeprefix("group:")
    lines = err.read_text().strip().splitlines()
    if name == "SIGKILL":
        assert rc == -9
        return
    # a second Ctrl-C while the process exits ends it by SIGINT itself (a shell shows 130)
    assert rc == EXIT[name] or (how.endswith("x2") and rc == -signal.SIGINT), (rc, lines)
    assert len(lines) == 1, lines
    assert "interrupted" in lines[0] and "results are kept" in lines[0], lines


@pytest.mark.parametrize(
    "how",
    ["SIGKILL", "SIGTERM", "SIGINT", "SIGINT x2", "group:SIGINT", "group:SIGINT x2"],
)
def test_signalled_study_leaves_no_worker_behind(how, reference, tmp_path):
    proc, err = _start(reference[1], tmp_path / "study")
    procs = _wait_for_workers(proc, "multiprocessing.spawn", 2)
    rc, outlived_s = _interrupt(proc, how, procs)
    assert outlived_s < GONE_WITHIN_S
    _assert_exit(how, rc, err)


def test_a_signal_while_the_workers_start_waits_until_each_has_its_data(monkeypatch) -> None:
    """Python 3.11 starts the pool's workers in ``submit``: a signal during the first submit is
    raised once every task is submitted, not between a worker's start and the write of its
    start-up data (the worker then read an empty pipe and printed an EOFError traceback: the
    SIGINT variant above, once in a full suite)."""
    from drafttwin.execution import executor
    from drafttwin.execution.interrupt import Interrupted, stop_on_signals

    submitted: list[cf.Future] = []
    submit = cf.ProcessPoolExecutor.submit

    def submit_then_signal(pool, fn, /, *args, **kwargs):
        submitted.append(submit(pool, fn, *args, **kwargs))
        if len(submitted) == 1:
            os.kill(os.getpid(), signal.SIGTERM)
        return submitted[-1]

    monkeypatch.setattr(cf.ProcessPoolExecutor, "submit", submit_then_signal)
    with pytest.raises(Interrupted), stop_on_signals():
        executor._run_local(abs, [(0, -1), (1, -2), (2, -3)], lambda i, r: None, 2, None)
    assert len(submitted) == 3


@pytest.mark.parametrize("wrapped", [True, False])
def test_an_interruption_inside_compiled_code_is_one_line(wrapped, monkeypatch, tmp_path) -> None:
    """A SIGTERM whose handler raised while numba's dispatcher ran Python (loading a cached
    function) comes back as a SystemError caused by the interruption: `reproduce` stopped in
    its data preparation printed that traceback (exit 1). It is the interruption: one line,
    exit 143. Any other SystemError is not swallowed."""
    from drafttwin.execution.interrupt import Interrupted
    from drafttwin.studies.paper.run import Study

    def prepare_data(self, series):
        stop = Interrupted(signal.SIGTERM, "finished results are kept")
        if wrapped:
            raise SystemError("CPUDispatcher returned a result with an exception set") from stop
        raise SystemError("a real fault of compiled code")

    monkeypatch.setattr(Study, "prepare_data", prepare_data)
    result = CliRunner().invoke(app, ["reproduce", "--out", str(tmp_path / "study")])
    if wrapped:
        assert result.exit_code == 143, result.output
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and "interrupted by SIGTERM" in lines[0], lines
    else:
        assert isinstance(result.exception, SystemError)


# the SIGTERM variant is a second one of the same resume (long, as are the Ray study's
# SIGKILL and group SIGINT: the process executor's test covers them every run)
@pytest.mark.parametrize("how", ["SIGKILL", pytest.param("SIGTERM", marks=pytest.mark.long)])
def test_rerun_after_a_kill_gives_the_numbers_of_an_uninterrupted_run(how, reference, tmp_path):
    out = tmp_path / "study"
    proc, _ = _start(reference[1], out)
    procs = _wait_for_workers(proc, "multiprocessing.spawn", 2)
    time.sleep(2.0)  # let some tasks finish: the rerun must resume, not start over
    _interrupt(proc, how, procs)
    assert not (out / "grid.json").exists()
    subprocess.run(_command(out), check=True, timeout=600, stdout=subprocess.DEVNULL)
    assert _numbers(out) == reference[0]


@pytest.mark.slow
@pytest.mark.parametrize("how", [pytest.param("SIGKILL", marks=pytest.mark.long), "SIGTERM",
                                 pytest.param("group:SIGINT", marks=pytest.mark.long)])  # fmt: skip
def test_signalled_ray_study_leaves_no_ray_process_behind(how, reference, tmp_path):
    pytest.importorskip("ray")
    proc, err = _start(reference[1], tmp_path / "study", "--executor", "ray")
    procs = _wait_for_workers(proc, "ray::", 3)  # two agents and a worker (process titles)
    time.sleep(1.0)  # the raylet starts its agents and further workers meanwhile
    procs |= _descendants(proc.pid)
    rc, outlived_s = _interrupt(proc, how, procs)
    assert outlived_s < GONE_WITHIN_S
    _assert_exit(how, rc, err)


# ---- bad executor options -------------------------------------------------------------------
BAD_OPTIONS = {
    "unknown executor": (["--executor", "bogus"], "--executor"),
    "executor in capitals": (["--executor", "RAY"], "--executor"),
    "empty executor": (["--executor", ""], "--executor"),
    "zero workers": (["--workers", "0"], "--workers"),
    "negative workers": (["--workers", "-1"], "--workers"),
    "100000 workers": (["--workers", "100000"], "--workers"),
    "1e12 workers": (["--workers", str(10**12)], "--workers"),
    "address without ray": (["--address", "127.0.0.1:6379"], "--address"),
    "address without port": (["--executor", "ray", "--address", "nonsense"], "--address"),
    "port out of range": (["--executor", "ray", "--address", "127.0.0.1:99999"], "--address"),
    "nothing listening": (["--executor", "ray", "--address", "127.0.0.1:1"], "--address"),
    "empty ray:// address": (["--executor", "ray", "--address", "ray://"], "--address"),
}


@pytest.mark.parametrize("command", ["reproduce", "grid-search"])
@pytest.mark.parametrize("case", list(BAD_OPTIONS))
def test_bad_executor_option_is_refused_before_the_data_are_prepared(command, case, tmp_path):
    args, option = BAD_OPTIONS[case]
    out = tmp_path / "study"
    t0 = time.perf_counter()
    res = CliRunner().invoke(app, [command, "--quiet", "--out", str(out), *args])
    assert res.exit_code == 2, res.output
    lines = res.output.strip().splitlines()
    # the project's user error: one line naming the option, then its fix
    assert lines[0].startswith("error: ") and option in lines[0], lines
    assert len(lines) <= 2 and "Traceback" not in res.output, lines
    assert not out.exists()  # nothing read, prepared or cached
    assert time.perf_counter() - t0 < 10.0


PLAIN_COMMANDS = {
    "generate": ["generate", "--duration", "120", "--sliver", "--quiet", "--out", "r.csv"],
    "fit": ["fit", "--model", "parallel", "--epochs", "50", "--set", "patience=none", "--quiet",
            "--out", "m.dtm"],
    # numba's compiled RK4 while it streams the file (SIGINT was a SystemError traceback;
    # SIGTERM left the temporary file)
    "simulate": ["simulate", "--duration", "600", "--rate", "1000", "--quiet", "--out", "s.csv"],
    "calibrate": ["calibrate", "--data", "default", "--quiet", "--out", "c.toml"],
    # the physics at 2 kHz in numba, then the drafting kernel (SIGINT: a 79-line traceback,
    # SIGTERM: silent)
    "sliver": ["sliver", "simulate", "--duration", "600", "--quiet", "--out", "sl.csv"],
}  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize(("command", "signum"), [("generate", signal.SIGTERM),
                         ("fit", signal.SIGTERM), ("simulate", signal.SIGTERM),
                         ("simulate", signal.SIGINT), ("calibrate", signal.SIGINT),
                         ("sliver", signal.SIGINT), ("sliver", signal.SIGTERM)])  # fmt: skip
def test_a_plain_command_stops_on_a_signal_in_one_line_leaving_no_file(
    tmp_path: Path, command: str, signum: int
) -> None:
    """``generate`` (while it writes, too), a fit without --tune, ``simulate`` and
    ``calibrate``: exit 128 + signal within 5 s, one line, no traceback, no output file and
    no temporary beside it."""
    proc = subprocess.Popen([sys.executable, "-m", "drafttwin", *PLAIN_COMMANDS[command]],
                            cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)  # fmt: skip
    time.sleep(6.0)  # past the imports, into the work
    start = time.monotonic()
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=30)
    assert time.monotonic() - start < 5
    name = signal.Signals(signum).name
    assert proc.returncode == 128 + signum and "Traceback" not in err, err
    assert f"interrupted by {name}" in err and len(err.strip().splitlines()) == 1, err
    assert [p.name for p in tmp_path.iterdir()] == [], list(tmp_path.iterdir())
