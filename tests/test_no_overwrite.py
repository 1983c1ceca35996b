"""Nothing overwritten (issue 27, item 6): every command that writes a file beside its --out
(``calibrate``: its report; ``generate``: the plant record's truth file and sidecar, and its
sliver files, tested in test_plant) refuses a file of that name that it did not write."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from drafttwin.cli import app
from drafttwin.cli.calibrate_cmds import REPORT_KIND, report_path
from drafttwin.errors import ConfigError

runner = CliRunner()


def test_calibrate_report_has_a_name_of_its_own(tmp_path: Path) -> None:
    out = tmp_path / "cal.toml"
    assert report_path(out) == tmp_path / "cal.calibration.json"  # not cal.json: a sidecar
    report_path(out).write_text(json.dumps({"report": REPORT_KIND}))
    assert report_path(out) == tmp_path / "cal.calibration.json"  # its own: replaced
    report_path(out).write_text(json.dumps({"files": {"truth": "cal.calibration.truth.csv"}}))
    with pytest.raises(ConfigError, match="not a report of drafttwin calibrate"):
        report_path(out)


@pytest.mark.parametrize("beside", ["rec.json", "rec.truth.csv"])
def test_generate_refuses_files_beside_out_that_it_did_not_write(tmp_path, beside) -> None:
    (tmp_path / beside).write_text("mine\n")
    result = runner.invoke(app, ["generate", "--duration", "0.2", "--out",
                                 str(tmp_path / "rec.csv")])  # fmt: skip
    assert result.exit_code == 2 and f"{beside} exists" in result.output, result.output
    assert (tmp_path / beside).read_text() == "mine\n" and not (tmp_path / "rec.csv").exists()


def test_generate_replaces_its_own_earlier_record(tmp_path: Path) -> None:
    files = {"measured": "rec.csv", "truth": "rec.truth.csv"}
    (tmp_path / "rec.json").write_text(json.dumps({"files": files}))
    (tmp_path / "rec.truth.csv").write_text("old\n")
    result = runner.invoke(app, ["generate", "--duration", "0.2", "--out",
                                 str(tmp_path / "rec.csv")])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert json.loads((tmp_path / "rec.json").read_text())["files"]["measured"] == "rec.csv"
    assert (tmp_path / "rec.truth.csv").read_text() != "old\n"


def test_generate_refuses_to_write_over_the_machine_it_reads(tmp_path: Path) -> None:
    rec = str(tmp_path / "rec.csv")
    assert runner.invoke(app, ["generate", "--duration", "0.2", "--out", rec]).exit_code == 0
    machine = (tmp_path / "rec.json").read_text()
    result = runner.invoke(app, ["generate", "--duration", "0.3", "--out", rec, "--machine",
                                 str(tmp_path / "rec.json")])  # fmt: skip
    assert result.exit_code == 2 and "is both --machine and the sidecar of --out" in result.output
    assert (tmp_path / "rec.json").read_text() == machine


def test_calibrate_refuses_params_that_name_nothing(tmp_path: Path) -> None:
    result = runner.invoke(app, ["calibrate", "--data", "default", "--params", " , ",
                                 "--out", str(tmp_path / "c.toml")])  # fmt: skip
    assert result.exit_code == 2 and "--params names no parameter" in result.output
    assert not (tmp_path / "c.toml").exists()
