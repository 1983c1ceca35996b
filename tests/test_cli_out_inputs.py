"""An output file is never one of the command's inputs, and ``fit --out`` never replaces a
file that is not a model file: the refusal comes before any work, and the file is untouched."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from typer.testing import CliRunner

from drafttwin.cli import app

runner = CliRunner()
EXAMPLES = Path(__file__).resolve().parents[1] / "docs" / "examples"


def _refused(args: list[str]) -> str:
    result = runner.invoke(app, args)
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    return " ".join(result.output.split())


@pytest.fixture
def record(tmp_path: Path) -> Path:
    path = tmp_path / "r.csv"
    path.write_text("t,u,y\n" + "".join(f"{0.02 * (k + 1):.2f},4,{30 + k % 3}\n"
                                        for k in range(200)))  # fmt: skip
    return path


@pytest.mark.parametrize("out_first", [False, True])
def test_fit_and_predict_refuse_an_out_that_is_an_input(record: Path, out_first: bool) -> None:
    before = record.read_bytes()
    opts = ["--outputs", "y", "--inputs", "u", "--mechanistic",
            f"config:{EXAMPLES / 'belt_drive.toml'}"]  # fmt: skip
    data, out = ["--data", str(record)], ["--out", str(record)]
    said = _refused(
        ["fit", "--model", "parallel", *(out + data if out_first else data + out), *opts]
    )
    assert "is both --data and --out" in said and "give --out another file name" in said
    said = _refused(["predict", "--model", str(record.with_suffix(".dtm")), "--data", str(record),
                     "--out", str(record.parent / "." / record.name)])  # fmt: skip
    assert "is both --data and --out" in said
    assert record.read_bytes() == before


def test_a_link_to_the_input_is_the_input(record: Path) -> None:
    link = record.parent / "link.csv"
    os.symlink(record, link)
    before = record.read_bytes()
    said = _refused(["simulate", "--config", str(EXAMPLES / "belt_drive.toml"), "--setpoints",
                     str(link), "--out", str(record)])  # fmt: skip
    assert "is both --setpoints and --out" in said
    assert record.read_bytes() == before


def test_the_physics_file_is_an_input(record: Path, tmp_path: Path) -> None:
    config = tmp_path / "drive.toml"
    config.write_text((EXAMPLES / "belt_drive.toml").read_text())
    said = _refused(["fit", "--model", "parallel", "--data", str(record), "--outputs", "y",
                     "--inputs", "u", "--mechanistic", f"config:{config}", "--out", str(config)])  # fmt: skip
    assert "is both --mechanistic and --out" in said


def test_fit_replaces_no_file_that_is_not_a_model(record: Path, tmp_path: Path) -> None:
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes\n")
    said = _refused(["fit", "--model", "parallel", "--data", str(record), "--outputs", "y",
                     "--inputs", "u", "--mechanistic", f"config:{EXAMPLES / 'belt_drive.toml'}",
                     "--out", str(notes)])  # fmt: skip
    assert "exists and is not a model file" in said and "--out" in said
    assert notes.read_text() == "my notes\n"


@pytest.mark.parametrize("option", ["--data", "--test-data"])
@pytest.mark.parametrize("value", ["", ",", " , "])
def test_a_file_list_that_names_no_file_is_refused(record: Path, option: str, value: str) -> None:
    args = ["fit", "--model", "gru", "--outputs", "y", "--out", str(record.with_suffix(".dtm"))]
    data = ["--data", str(record)] if option == "--test-data" else []
    said = _refused([*args, *data, option, value])
    assert f"{option}: names no file" in said


def test_sliver_simulate_writes_no_sliver_over_its_speed_file(record: Path) -> None:
    """It had printed "wrote r.csv" over the speed record it read (its sidecar left beside
    a file that no longer matched it)."""
    before = record.read_bytes()
    said = _refused(["sliver", "simulate", "--speeds", str(record), "--out", str(record),
                     "--fibre-scale", "50", "--quiet"])  # fmt: skip
    assert "is both --speeds and --out" in said
    assert record.read_bytes() == before


@pytest.mark.parametrize(("command", "name"), [("reproduce", "predictions.csv"),
                                               ("reproduce", "metrics.csv"),
                                               ("grid-search", "grid.json")])  # fmt: skip
def test_a_study_writes_no_file_of_its_folder_over_its_data(
    record: Path, tmp_path: Path, command: str, name: str
) -> None:
    """reproduce --data OUT/predictions.csv --out OUT had replaced the measurements with the
    study's predictions, without a word."""
    data = tmp_path / name
    data.write_bytes(record.read_bytes())
    said = _refused([command, "--data", str(data), "--out", str(tmp_path), "--quiet"])
    assert f"is --data, and the command writes its {name} in --out" in said
    assert data.read_bytes() == record.read_bytes()


@pytest.mark.parametrize("command", ["reproduce", "grid-search"])
def test_a_study_refuses_a_record_too_short_before_any_fit(tmp_path: Path, command: str) -> None:
    """A 50-row record had passed the grid and failed in MD-S-L's data-model folds, naming
    --train-fraction and --set window, which reproduce does not have."""
    from drafttwin.plant import Plant

    path = tmp_path / "short.csv"
    Plant().run(0.5, 100.0, seed=1).write(path)
    said = _refused([command, "--data", str(path), "--out", str(tmp_path / "s"), "--quiet"])
    assert "--data: the record gives 35 training rows (70% of 50)" in said, said
    assert "give a record of at least" in said and "--train-fraction" not in said


@pytest.mark.parametrize(
    ("option", "value"),
    [("--units", "y=m,y=rad/s"), ("--set", "window=10,window=12"),
     ("--columns", "t=time,t=time_s")],
)  # fmt: skip
def test_a_name_given_twice_in_a_list_of_pairs_is_refused(
    record: Path, option: str, value: str
) -> None:
    """The last value had won without a word (``--units y=m,y=rad/s`` reported rad/s)."""
    out = record.with_suffix(".dtm")
    said = _refused(["fit", "--model", "gru", "--data", str(record), "--outputs", "y",
                     "--inputs", "u", "--epochs", "1", "--out", str(out), option, value])  # fmt: skip
    assert f"{option}: " in said and "is given twice" in said and not out.exists()
