"""Hostile command lines and hostile file systems: every one ends with one error message
naming the option (and the path), exit code 2, no traceback, nothing half-written.

Parametrised over every numeric option of every command x (0, -1, nan, inf, 1e300, text), and
over I/O conditions made for real: a read-only tmpfs, a full tmpfs, ``ulimit -f``, a folder
and a file without permission (root's override dropped), an output that is a folder, a parent
that is a file, missing parents. In-process where the condition allows; in a subprocess for
the file-size limit and the dropped permission override (these are per process).
"""

from __future__ import annotations

import contextlib
import functools
import json
import re
import subprocess
from dataclasses import dataclass
from pathlib import Path
from unittest import mock

import numpy as np
import pytest
import typer
import typer.testing
from typer.testing import CliRunner

import drafttwin as dt
from drafttwin._json import dumps_strict
from drafttwin._limits import MAX_RK4_STEPS, check_rk4_steps
from drafttwin.cli import app
from drafttwin.cli._bounds import BOUNDS
from drafttwin.errors import ConfigError

from ._cli import (
    ENDLESS,
    HOSTILE,
    IO_CASES,
    NUMERIC_OPTIONS,
    OLD,
    ZERO_OK,
    IoCase,
    Outcome,
    argv_for,
    can_drop_root_override,
    leftovers,
    numeric_cases,
    old_file,
    run_batch,
    tmpfs,
    without_root_override,
)

CLI_SRC = Path(__file__).resolve().parents[2] / "src" / "drafttwin" / "cli"


@functools.cache
def _command(typer_app: typer.Typer) -> object:
    return typer.main.get_command(typer_app)


def invoke(argv: list[str]) -> Outcome:
    # the click command is built once (0.1 s each time otherwise, x 200 cases)
    with mock.patch.object(typer.testing, "_get_command", _command):
        res = CliRunner().invoke(app, argv)
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        raise res.exception  # a traceback: show it
    return Outcome(res.exit_code, res.stdout, res.stderr)


def _commands() -> dict[str, object]:
    """Every leaf command of the CLI by its path ('simulate', 'benchmark emps')."""
    out: dict[str, object] = {}

    def walk(cmd: object, path: list[str]) -> None:
        subs = getattr(cmd, "commands", None)
        if subs:
            for name, sub in subs.items():
                walk(sub, [*path, name])
        else:
            out[" ".join(path)] = cmd

    walk(typer.main.get_command(app), [])
    return out


def _numeric_options(cmd: object) -> list[str]:
    return [p.opts[0] for p in cmd.params  # type: ignore[attr-defined]
            if p.type_descriptor.annotation in (int, float)]  # fmt: skip


# -- numbers --------------------------------------------------------------------------------


def test_the_cases_cover_every_numeric_option_of_every_command() -> None:
    found = {name: _numeric_options(cmd) for name, cmd in _commands().items()}
    found = {name: opts for name, opts in found.items() if opts}
    assert found == NUMERIC_OPTIONS  # a new numeric option must be listed (and bounded)
    assert all(opt in BOUNDS for opts in found.values() for opt in opts)


@pytest.mark.parametrize(("command", "option", "label"), numeric_cases(),
                         ids=[f"{c} {o} {v}" for c, o, v in numeric_cases()])  # fmt: skip
def test_a_hostile_number_is_refused_in_one_line_naming_the_option(
    command: str, option: str, label: str, tmp_path: Path
) -> None:
    out = invoke(argv_for(command, option, label, tmp_path, tmp_path / "model.pt"))
    assert out.kind == "clean", out.stderr
    assert option in out.stderr
    if label != "text":  # the range is named: "--rate 0: must be > 0 and <= 1e+06 Hz"
        assert BOUNDS[option].describe() in out.stderr
    assert not list(tmp_path.iterdir())  # refused before any work


def test_the_step_option_takes_what_a_drive_train_file_takes() -> None:
    """--dt took up to 1 s where a file's [solver] dt_s stops at 1e-3 s."""
    from drafttwin.mechanics.components import Solver

    limits = {k: getattr(m, k) for m in Solver.model_fields["dt_s"].metadata
              for k in ("ge", "le") if hasattr(m, k)}  # fmt: skip
    bound = BOUNDS["--dt"]
    assert (bound.low, bound.low_inclusive, bound.high) == (limits["ge"], True, limits["le"])


@pytest.mark.parametrize("option", sorted(BOUNDS))
def test_each_range_accepts_its_edges_and_refuses_beyond(option: str) -> None:
    bound = BOUNDS[option]
    assert bound.accepts(bound.high) and not bound.accepts(bound.high * 1.001)
    assert bound.accepts(bound.low) == bound.low_inclusive
    if option in ZERO_OK:  # seeds, tolerances, the settling time may be zero
        assert bound.accepts(0)
    assert not any(bound.accepts(v) for k, v in HOSTILE.items() if v is not None
                   and k not in ("0", "-1"))  # nan, inf, 1e300  # fmt: skip


def test_a_step_that_would_never_end_is_refused_at_once() -> None:
    out = invoke(["simulate", "--dt", "1e-7", "--duration", "1e5", "--quiet"])
    assert out.kind == "clean" and "--dt" in out.stderr and "RK4 steps" in out.stderr
    with pytest.raises(ConfigError, match="RK4 steps"):
        check_rk4_steps(1.0, 1.0 / MAX_RK4_STEPS / 10)
    assert check_rk4_steps(1.0, 1e-4, settle_s=1.0) == 20_000


@pytest.mark.parametrize("name", list(ENDLESS))
def test_numbers_in_range_that_ask_for_endless_work_are_refused_at_once(
    name: str, tmp_path: Path
) -> None:
    out = invoke([a.format(tmp=tmp_path) for a in ENDLESS[name]])
    assert out.kind == "clean", out.stderr
    assert "a run may" in out.stderr and not list(tmp_path.iterdir())


@pytest.mark.parametrize("argv", [["simulate", "--nope"], ["nosuchcommand"],
                                  ["fit", "--model", "gru"], ["simulate", "--rate"]],
                         ids=["unknown option", "unknown command", "missing option",
                              "option without value"])  # fmt: skip
def test_usage_errors_are_one_line_not_a_box(argv: list[str]) -> None:
    out = invoke(argv)
    assert out.kind == "clean", out.stderr
    assert "--help" in out.stderr


DATA_OPTIONS = {
    "--outputs",
    "--inputs",
    "--units",
    "--time-column",
    "--columns",
    "--unit-check",
    "--rate-tolerance",
}


@pytest.mark.parametrize("command", ["inspect", "fit", "predict", "evaluate", "calibrate"])
def test_every_command_reading_your_data_takes_the_same_data_options(command: str) -> None:
    cmd = _commands()[command]
    assert DATA_OPTIONS.issubset(p.opts[0] for p in cmd.params)  # type: ignore[attr-defined]


def test_the_study_maps_a_files_columns_as_its_error_says(tmp_path: Path) -> None:
    # reproduce and grid-search run the paper's study on the FA320A layout; a file with other
    # column names is refused with a fix naming --columns, which they take
    import pandas as pd

    from drafttwin.cli.study_cmds import StudyOptions

    default = dt.load_default()
    path = dt.write_measurements(default, tmp_path / "mill.csv")
    frame = pd.read_csv(path)
    theirs = {"front": "r1", "second": "r2", "third": "r3", "back": "r4"}
    frame.rename(columns=theirs).to_csv(path, index=False)
    for command in ("reproduce", "grid-search"):
        out = invoke([command, "--data", str(path), "--out", str(tmp_path / "study")])
        assert out.kind == "clean" and "--columns r1=front" in out.stderr, out.stderr
        assert "--columns" in {p.opts[0] for p in _commands()[command].params}  # type: ignore[attr-defined]
    mapped = ",".join(f"{v}={k}" for k, v in theirs.items())
    _, series, _ = StudyOptions(data=str(path), columns=mapped).study(tmp_path / "study")
    assert series.channels == default.channels
    np.testing.assert_allclose(series.values, default.values, rtol=1e-9)


# -- strict JSON ----------------------------------------------------------------------------


def _strict(text: str) -> object:
    def refuse(name: str) -> None:
        raise ValueError(f"{name} is not JSON")

    return json.loads(text, parse_constant=refuse)


def test_dumps_strict_turns_non_finite_numbers_into_null() -> None:
    doc = {"a": float("nan"), "b": [np.float32("inf"), -np.inf], "c": np.arange(2), "d": 1.5}
    assert _strict(dumps_strict(doc)) == {"a": None, "b": [None, None], "c": [0, 1], "d": 1.5}


@pytest.mark.parametrize("argv", [["kinematics", "--json"], ["inspect", "default", "--json"]])
def test_json_output_parses_as_strict_json(argv: list[str]) -> None:
    out = invoke(argv)
    assert out.exit_code == 0, out.stderr
    assert isinstance(_strict(out.stdout), dict)


def test_no_cli_module_calls_json_dumps_directly() -> None:
    # every JSON the CLI prints or writes goes through dumps_strict / print_json
    offenders = [f"{p.name}:{i}" for p in sorted(CLI_SRC.glob("*.py"))
                 for i, line in enumerate(p.read_text().splitlines(), 1)
                 if re.search(r"\bjson\.dumps?\(", line)]  # fmt: skip
    assert offenders == []


# -- files and folders ----------------------------------------------------------------------


IN_PROCESS = [c for c in IO_CASES if c.preexec is None]
OWN_PROCESS = [c for c in IO_CASES if c.preexec is not None]


@dataclass
class Ran:
    """One I/O case run: how it ended, the watched file's text after, files left behind."""

    out: Outcome
    kept: str | None
    left: list[Path]
    folder: Path


def _after(out: Outcome, folder: Path, watched: Path | None) -> Ran:
    kept = watched.read_text() if watched is not None and watched.is_file() else None
    left = [p for p in leftovers(folder) if p.name != "filler.bin"]
    return Ran(out, kept, left, folder)


@pytest.fixture(scope="module")
def own_process_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Ran]:
    """The cases that need a process of their own (a file-size limit, no permission
    override): one subprocess per condition runs all of its cases (one start-up each)."""
    runs: dict[str, Ran] = {}
    folders = []
    with contextlib.ExitStack() as stack:
        groups: dict[object, list] = {}
        for case in OWN_PROCESS:
            if case.preexec is without_root_override and not can_drop_root_override():
                continue
            folder = tmp_path_factory.mktemp("io")
            folders.append(folder)
            argv, watched = case.setup(folder, folder / "model.pt", stack)
            groups.setdefault(case.preexec, []).append((case, folder, argv, watched))
        for preexec, items in groups.items():
            outs = run_batch([argv for _, _, argv, _ in items], preexec=preexec)  # type: ignore[arg-type]
            for (case, folder, _, watched), out in zip(items, outs, strict=True):
                runs[case.name] = _after(out, folder, watched)
    yield runs
    for folder in folders:
        subprocess.run(["chmod", "-R", "u+rwx", str(folder)], check=False)


def _check(case: IoCase, ran: Ran) -> None:
    assert ran.left == []  # no temporary file left behind
    if case.expect == "written":
        assert ran.out.exit_code == 0, ran.out.stderr
        assert ran.kept is not None and ran.kept.startswith("time,")
        return
    assert ran.out.kind == "clean", ran.out.stderr
    assert str(ran.folder) in ran.out.stderr  # the path is named (and its option, if any)
    assert ran.kept in (None, OLD)  # an old file is intact


@pytest.mark.parametrize("case", IN_PROCESS, ids=[c.name for c in IN_PROCESS])
def test_an_io_failure_is_one_message_and_leaves_nothing_half_written(
    case: IoCase, tmp_path: Path
) -> None:
    with contextlib.ExitStack() as stack:
        argv, watched = case.setup(tmp_path, tmp_path / "model.pt", stack)
        ran = _after(invoke(argv), tmp_path, watched)
    if watched is not None and case.expect == "clean":
        assert ran.kept == OLD or not watched.exists()
    _check(case, ran)


@pytest.mark.parametrize("case", OWN_PROCESS, ids=[c.name for c in OWN_PROCESS])
def test_a_permission_or_size_limit_failure_is_one_message(
    case: IoCase, own_process_runs: dict[str, Ran]
) -> None:
    if case.name not in own_process_runs:
        pytest.skip("needs root (to drop the permission override) for a real EACCES")
    _check(case, own_process_runs[case.name])


def test_files_written_together_are_all_kept_old_when_one_does_not_fit(tmp_path: Path) -> None:
    # calibrate's train and report: a full disk half-way leaves both old files, no temp files
    from drafttwin._io import write_texts_atomic
    from drafttwin.cli._oserrors import describe

    with tmpfs(tmp_path / "disk", size="64k") as disk:
        toml, report = old_file(disk / "c.toml"), old_file(disk / "c.json")
        with pytest.raises(OSError) as err:
            write_texts_atomic({toml: "new\n", report: "x" * 200_000})
        assert toml.read_text() == OLD and report.read_text() == OLD
        assert leftovers(disk) == []
        assert err.value.filename == str(report)  # named by the target, not the temp file
        assert "no space left" in describe(err.value).message


def test_a_device_given_as_output_stays_a_device() -> None:
    """``--out /dev/null`` discards the output; a rename onto it would (as root) put a plain
    file where the device was, and every later write to /dev/null would land in it."""
    import stat

    from drafttwin._io import atomic_path

    device = Path("/dev/null")
    if not device.exists() or not stat.S_ISCHR(device.stat().st_mode):
        pytest.skip("no /dev/null device here")
    with atomic_path(device) as path:
        path.write_text("discarded\n")
    assert stat.S_ISCHR(device.stat().st_mode)
    assert device.read_text() == ""


def test_a_unit_declared_for_a_roller_or_the_motor_is_read_as_declared(tmp_path: Path) -> None:
    # --units front=rpm had made the default roller an input too ("declared both as an output
    # and as an input"); motor=rpm an input channel named motor
    path = dt.write_measurements(dt.load_default(), tmp_path / "r.csv")
    for units in ("front=rpm", "motor=rpm", "front=rpm,supply_hz=Hz"):
        out = invoke(["inspect", str(path), "--units", units])
        assert out.exit_code == 0, (units, out.stderr)
    out = invoke(["inspect", str(path), "--units", "motor=rad/s"])
    assert out.kind == "clean" and "the motor column is read in rpm, not rad/s" in out.stderr


def test_a_written_time_column_reads_back_exactly(tmp_path: Path) -> None:
    # at the values' 9 significant digits an epoch time (1.8e9 s) lost everything below 10 s:
    # every 100-Hz row of `twin query --out x.csv` and of `predict` had one time
    import pandas as pd

    from drafttwin.cli._common import write_frame

    time = 1795996457.0 + np.arange(5) * 0.01
    frame = pd.DataFrame({"time": time, "front": 1814.123456789123 + np.arange(5)})
    frame.loc[2, "time"] = np.nan
    write_frame(frame, tmp_path / "x.csv")
    back = pd.read_csv(tmp_path / "x.csv")
    np.testing.assert_array_equal(back["time"].to_numpy(), frame["time"].to_numpy())
    np.testing.assert_allclose(back["front"], frame["front"], rtol=5e-9)  # 9 digits
    # a time column named as the user's file named it (predict keeps it): the first, rising
    renamed = frame.dropna().rename(columns={"time": "stamp"})
    write_frame(renamed, tmp_path / "y.csv")
    np.testing.assert_array_equal(pd.read_csv(tmp_path / "y.csv")["stamp"], renamed["stamp"])
