"""docs/sliver.md runs as written: its Python block and its example commands (an eccentric
front roller found from the plant's sliver record)."""

from __future__ import annotations

import shlex
from pathlib import Path

import pytest
from typer.testing import CliRunner

from drafttwin.cli import app

from ..test_docs import DOCS, blocks, run_python

pytestmark = pytest.mark.slow


def test_the_python_example_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    ns = run_python(DOCS / "sliver.md")
    assert ns["ev"].count_ktex == pytest.approx(33 / 6.574, rel=5e-3)  # type: ignore[attr-defined]


def test_the_eccentric_roller_example_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    block = next(b for b in blocks(DOCS / "sliver.md", "bash") if "sliver diagnose" in b)
    output = ""
    for line in block.strip().splitlines():
        argv = shlex.split(line)
        assert argv[0] == "drafttwin"
        result = runner.invoke(app, argv[1:])
        assert result.exit_code == 0, result.output
        output = result.output
    assert "14.14 cm" in output and "roller front" in output
    assert (tmp_path / "ecc.html").is_file()
