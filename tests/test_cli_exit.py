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
