"""The console script's quick exit: only the command that asked for it, in its own run."""

from __future__ import annotations

import pytest

from drafttwin.cli._exit import quick_exit_due, work_done


def test_a_quick_exit_asked_by_an_earlier_command_does_not_end_the_next(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A test process runs many commands: one that asked for a quick exit in-process (as
    ``twin run`` does through CliRunner) must not make the next ``main()`` leave the process."""
    from drafttwin.cli import main

    work_done()
    monkeypatch.setattr("sys.argv", ["drafttwin", "inspect", "/nonexistent/plant.csv"])
    with pytest.raises(SystemExit) as info:
        main()
    assert info.value.code == 2 and not quick_exit_due()


@pytest.mark.parametrize("signum", ["SIGTERM", "SIGINT"])
def test_a_signal_while_the_command_starts_says_so(signum: str, tmp_path) -> None:
    """SIGTERM in the first second (Python still importing; seconds on a busy machine) died
    silently with 143, Ctrl-C there printed a KeyboardInterrupt traceback: one line now, exit
    128 + signal, nothing written."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "plant.csv"
    proc = subprocess.Popen([sys.executable, "-m", "drafttwin", "generate", "--duration", "600",
                             "--out", str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "NO_COLOR": "1"})  # fmt: skip
    time.sleep(0.3)
    sig = getattr(signal, signum)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + sig, err
    # the wording of a command's own stop: which handler meets the signal depends on load
    assert err.strip() == f"error: interrupted by {signum}; nothing was written", err
    assert list(tmp_path.iterdir()) == []


def test_only_the_command_itself_says_it_was_stopped(monkeypatch: pytest.MonkeyPatch) -> None:
    """A spawned worker (the twin's cause ranking) imports the CLI with the command's own
    ``sys.argv``: it took the start-up handler and printed "interrupted by SIGTERM" when its
    parent ended it at a normal end."""
    from drafttwin.cli import _run_as_the_command

    monkeypatch.setattr("sys.argv", ["/venv/bin/drafttwin", "twin", "run"])
    monkeypatch.setattr("sys.orig_argv", ["python", "/venv/bin/drafttwin", "twin", "run"])
    assert _run_as_the_command()
    monkeypatch.setattr("sys.orig_argv", ["python", "-c", "from multiprocessing.spawn import "
                                          "spawn_main; spawn_main(tracker_fd=5, pipe_handle=7)",
                                          "--multiprocessing-fork"])  # fmt: skip
    assert not _run_as_the_command()
    monkeypatch.setattr("sys.argv", ["-c", "twin", "run"])  # a program importing the CLI
    monkeypatch.setattr("sys.orig_argv", ["python", "-c", "...", "twin", "run"])
    assert not _run_as_the_command()
