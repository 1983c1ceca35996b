"""Single samples that no drafting roller can produce are refused, named by row.

The median-based unit check let a lone 1e12 (a bit error) or a deeply negative sample (a
machine that cannot reverse) through; the per-sample check refuses them with the column and
row, while the torsional swing of a real stop (the plant's start-ups dip to -0.6 rpm) passes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from drafttwin.cli import app
from drafttwin.data import read_measurements
from drafttwin.datasets import default_path
from drafttwin.errors import DataError

ROLLERS = ["front", "second", "third", "back"]


def _csv(tmp_path: Path, edit: dict[tuple[int, str], float]) -> Path:
    frame = pd.read_parquet(default_path(), columns=["time", *ROLLERS, "supply_hz"]).iloc[:2000]
    for (row, col), value in edit.items():
        frame.loc[row, col] = value
    path = tmp_path / "data.csv"
    frame.to_csv(path, index=False)
    return path


@pytest.mark.parametrize("roller", ROLLERS)
@pytest.mark.parametrize(("value", "words"), [(1e12, "above"), (2e5, "above"),
                                               (-500.0, "backwards"), (-1e12, "backwards")])  # fmt: skip
def test_an_impossible_sample_is_refused_by_row(
    tmp_path: Path, roller: str, value: float, words: str
) -> None:
    path = _csv(tmp_path, {(700, roller): value})
    with pytest.raises(DataError) as err:
        read_measurements(path)
    msg = err.value.message
    assert f"column '{roller}'" in msg and "row 701" in msg and words in msg


def test_the_swing_of_a_stop_passes(tmp_path: Path) -> None:
    edit = {(i, r): v for i in range(1500, 1600) for r in ROLLERS
            for v in [-0.6 if i % 7 == 0 else 0.0]}  # fmt: skip
    series = read_measurements(_csv(tmp_path, edit))
    assert np.nanmin(series.values) == pytest.approx(-0.6)


def test_the_check_can_be_skipped_for_a_machine_that_reverses(tmp_path: Path) -> None:
    series = read_measurements(_csv(tmp_path, {(700, "front"): -500.0}), check_units=False)
    assert np.nanmin(series.values[:, 0]) == -500.0


def test_the_cli_refuses_in_one_message(tmp_path: Path) -> None:
    res = CliRunner().invoke(app, ["inspect", str(_csv(tmp_path, {(5, "back"): 1e12}))])
    assert res.exit_code == 2 and "row 6" in res.output and "Traceback" not in res.output
