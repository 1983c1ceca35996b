"""The documentation runs: every Python example of docs/api.md, and every command and Python
block of the own-machine tutorial, in a fresh folder, as a user would type them."""

from __future__ import annotations

import json
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from drafttwin.cli import app

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def blocks(page: Path, language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", page.read_text(encoding="utf-8"), re.S)


def commands(page: Path) -> list[list[str]]:
    """The shell commands of a page's bash blocks (continuation lines joined, comments
    dropped)."""
    out = []
    for block in blocks(page, "bash"):
        text = block.replace("\\\n", " ")
        for line in text.splitlines():
            line = line.split(" #", 1)[0].strip()
            if line and not line.startswith("#"):
                out.append(shlex.split(line))
    return out


def run_python(page: Path) -> dict[str, object]:
    namespace: dict[str, object] = {"__name__": "__doc_example__"}
    for k, code in enumerate(blocks(page, "python")):
        exec(compile(code, f"{page.name} block {k + 1}", "exec"), namespace)
    return namespace


def test_api_examples_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    shutil.copy(DOCS / "examples" / "belt_drive.toml", tmp_path)
    monkeypatch.chdir(tmp_path)
    ns = run_python(DOCS / "api.md")
    assert ns["result"].metrics["y"].unit == "rad/s"  # type: ignore[attr-defined]
    assert (tmp_path / "parallel.dtm").is_file()


@pytest.mark.long  # a minute of fitting; test_api_examples_run runs the API's examples
def test_own_machine_tutorial_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    shutil.copytree(DOCS / "examples", tmp_path / "docs" / "examples")
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    outputs = {}
    for argv in commands(DOCS / "own-machine.md"):
        if argv[0] == "drafttwin":
            result = runner.invoke(app, argv[1:])
            assert result.exit_code == 0, (argv, result.output)
            outputs[" ".join(argv[1:3])] = result.stdout
        else:
            assert argv[0] == "python", argv
            done = subprocess.run([sys.executable, *argv[1:]], capture_output=True, text=True)
            assert done.returncode == 0, (argv, done.stderr)
    report = json.loads(outputs["evaluate --model"])
    assert report["task"] == "simulation" and report["channels"]["y"]["unit"] == "rad/s"
    assert (tmp_path / "predictions.csv").is_file()
    ns = run_python(DOCS / "own-machine.md")
    assert ns["result"].metrics["y"].rmse > 0  # type: ignore[attr-defined]
