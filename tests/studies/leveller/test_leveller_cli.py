"""``benchmark leveller``'s plan from its options: ``--quick`` takes ``--machines`` and
``--fault-cases`` too (it had ignored them without a word)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

import drafttwin.studies.leveller as leveller
from drafttwin.cli import app


@pytest.mark.parametrize(("args", "expected"), [
    (["--quick"], (2, 0, 80.0)),
    (["--quick", "--machines", "1", "--fault-cases", "2"], (1, 2, 80.0)),
    (["--machines", "3"], (3, 4, 300.0)),
    ([], (10, 4, 300.0)),
])  # fmt: skip
def test_the_plan_takes_the_options_given(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, args: list[str],
    expected: tuple[int, int, float],
) -> None:  # fmt: skip
    seen: list[Any] = []

    def fake(config: Any, workers: int, cache: Path, on_case: Any) -> dict[str, Any]:
        seen.append(config)
        raise SystemExit(0)  # the plan is what is checked, not the run

    monkeypatch.setattr(leveller, "run_benchmark", fake)
    CliRunner().invoke(app, ["benchmark", "leveller", *args, "--quiet", "--out",
                             str(tmp_path / "out")])  # fmt: skip
    (config,) = seen
    assert (config.machines, config.fault_cases, config.length_m) == expected
