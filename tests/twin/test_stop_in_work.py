"""Commands that ran under the start-up handler for their whole work (``inspect``, ``twin
fit-detector``, ``twin query``, ``twin audit``): a SIGTERM in their work printed the start-up
wording and left an ``--out`` temporary to chance. Each installs its own handler now: the
command's one line, exit 143. The test's own SIGTERM handler fails it where the signal reaches
no handler of the command."""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

from drafttwin.cli import app


@pytest.fixture
def unhandled_fails() -> Iterator[None]:
    def unhandled(signum: int, frame: object) -> None:
        raise AssertionError("SIGTERM reached no handler of the command")

    previous = signal.signal(signal.SIGTERM, unhandled)
    yield
    signal.signal(signal.SIGTERM, previous)


def _sigterm_in_the_work(*args: object, **kwargs: object) -> None:
    signal.raise_signal(signal.SIGTERM)
    time.sleep(2.0)  # the command's handler raises before this ends
    raise AssertionError("the signal did not stop the command")


def _stopped(argv: list[str]) -> None:
    result = CliRunner().invoke(app, argv)
    assert result.exit_code == 143, (result.output, result.exception)
    assert result.output.strip().splitlines() == [
        "error: interrupted by SIGTERM; nothing was written"
    ], result.output


def test_inspect_stops_in_its_work(monkeypatch, unhandled_fails) -> None:
    monkeypatch.setattr("drafttwin.cli.data_cmds.summarize", _sigterm_in_the_work)
    _stopped(["inspect", "default"])


def test_fit_detector_stops_in_its_work(monkeypatch, unhandled_fails, twin_files,
                                        tmp_path: Path) -> None:  # fmt: skip
    record, model = twin_files
    monkeypatch.setattr("drafttwin.diagnosis.residuals.record_features", _sigterm_in_the_work)
    out = tmp_path / "detector.json"
    _stopped(["twin", "fit-detector", "--model", str(model), "--healthy", str(record),
              "--out", str(out)])  # fmt: skip
    assert list(tmp_path.iterdir()) == []
