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


def test_the_table_cuts_no_figure_at_80_columns(monkeypatch) -> None:
    """At 80 columns the CV cells read "1.6…", the ratios "1.0…" and the feeds "long…"."""
    import io

    from rich.console import Console

    from drafttwin.cli import leveller_cmds

    buf = io.StringIO()
    monkeypatch.setattr(leveller_cmds, "console", Console(file=buf, width=80))
    case = {"case": 10, "feed": {"kind": "missing-sliver"}, "leveller_fault": "infeed-drift",
            "offset_mm": -25.0, "advice": {"recommended_action_point_mm": 698.61,
                                           "metres_used": 256.0},
            "brute_min_action_point_mm": 699.5, "error_mm": -0.9, "brute_min_cv_pct": 1.6543,
            "reached_cv_pct": 1.7012, "cv_ratio": 1.0284}  # fmt: skip
    leveller_cmds._print({"cases": [case], "summary": {}})
    out = buf.getvalue()
    assert "…" not in out
    for cell in ("missing-sliver", "1.654", "1.701", "1.028", "698.6", "699.5", "256", "set:"):
        assert cell in out, (cell, out)
