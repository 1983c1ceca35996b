"""Every command's --help reads as paragraphs: no ragged half-lines from the docstring's breaks."""

from __future__ import annotations

from typing import Any

import pytest
import typer
from typer.testing import CliRunner

from drafttwin.cli import app


def _commands(group: Any, prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    out = []
    for name, cmd in group.commands.items():
        path = (*prefix, name)
        out += _commands(cmd, path) if hasattr(cmd, "commands") else [path]
    return out


ROOT: Any = typer.main.get_command(app)  # typer's own click group
COMMANDS = _commands(ROOT)


def test_the_tree_has_every_group() -> None:
    assert {p[0] for p in COMMANDS} >= {"fit", "calibrate", "benchmark", "twin", "plant"}
    assert len(COMMANDS) > 20


@pytest.mark.parametrize("path", COMMANDS, ids=" ".join)
def test_help_paragraphs_are_reflowed(path: tuple[str, ...]) -> None:
    cmd = ROOT
    for name in path:
        cmd = cmd.commands[name]
    paragraphs = (cmd.help or "").split("\n\n")
    assert all("\n" not in p for p in paragraphs if not p.startswith("\b")), path
    # and rendered at 80 columns, a paragraph's lines fill the width but for its last
    res = CliRunner().invoke(app, [*path, "--help"], env={"COLUMNS": "80", "TERM": "dumb"})
    assert res.exit_code == 0, res.output
    blocks: list[list[str]] = [[]]
    for line in res.output.split("╭")[0].splitlines():
        if line.strip():
            blocks[-1].append(line.rstrip())
        else:
            blocks.append([])
    for lines in blocks:
        assert all(len(ln) > 40 for ln in lines[:-1]), (path, lines)
