"""A simulator file stamped with dates, as a logger or a plant historian writes it, is put on
its record's own seconds by the stamps (was refused: "non-numeric value
'2026-12-01T08:00:00.000000'", whatever the record): through the CLI and the library alike; a
stamped file of another day, or for a record timed in seconds, is refused in one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

import drafttwin as dt
from drafttwin.cli import app
from drafttwin.errors import DataError

runner = CliRunner()
STEP_S = 0.05
START = pd.Timestamp("2026-12-01T08:00:00")
READ = {"outputs": ["y"], "inputs": ["u"], "units": {"y": "m", "u": "V"}}
CLI = ["--outputs", "y", "--inputs", "u", "--units", "y=m,u=V"]


def _stamps(t: np.ndarray, start: pd.Timestamp) -> pd.Series:
    return pd.Series(start + pd.to_timedelta(t, unit="s")).dt.strftime("%Y-%m-%dT%H:%M:%S.%f")


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A record stamped from 08:00, and its physics three ways: in seconds, stamped from the
    same start, and stamped from one step earlier (one row more in front)."""
    path = tmp_path_factory.mktemp("simstamps")
    rng = np.random.default_rng(4)
    n = 240
    t = np.arange(n) * STEP_S
    u = np.repeat(rng.uniform(0.5, 2.0, n // 20 + 1), 20)[:n]
    physics = 1.0 + 0.5 * u + 0.2 * np.sin(1.3 * t)  # a ramp inside each step: a shift shows
    y = physics + 0.05 * np.cos(0.7 * t) + rng.normal(0, 0.01, n)
    pd.DataFrame({"timestamp": _stamps(t, START), "u": u, "y": y}).to_csv(
        path / "rec.csv", index=False
    )
    pd.DataFrame({"time": t, "y": physics}).to_csv(path / "sim_s.csv", index=False)
    pd.DataFrame({"timestamp": _stamps(t, START), "y": physics}).to_csv(
        path / "sim_stamped.csv", index=False
    )
    early = np.concatenate([[-STEP_S], t])
    pd.DataFrame({"timestamp": _stamps(early, START), "y": np.interp(early, t, physics)}).to_csv(
        path / "sim_early.csv", index=False
    )
    pd.DataFrame({"timestamp": _stamps(t, START + pd.Timedelta(days=1)), "y": physics}).to_csv(
        path / "sim_next_day.csv", index=False
    )
    pd.DataFrame({"time": t, "u": u, "y": y}).to_csv(path / "rec_s.csv", index=False)
    return path


def test_a_stamped_file_gives_what_the_same_file_in_seconds_gives(folder: Path) -> None:
    record = dt.read_measurements(folder / "rec.csv", **READ)
    assert record.metadata["start_time"] == START.isoformat()
    seconds = dt.MechanisticModel(str(folder / "sim_s.csv")).predict_values(record, ("y",))
    stamped = dt.MechanisticModel(str(folder / "sim_stamped.csv")).predict_values(record, ("y",))
    # equal but for the last bit: the file in seconds holds 0.05 * k as float64 text
    np.testing.assert_allclose(stamped, seconds, rtol=1e-15, atol=0)
    # one row earlier in front: moved by its stamps, so the same values at the record's rows
    early = dt.MechanisticModel(str(folder / "sim_early.csv"))
    early.match_records(record)
    np.testing.assert_allclose(early.predict_values(record, ("y",)), seconds, atol=1e-12)


def test_the_cli_fits_with_a_stamped_file_as_with_the_file_in_seconds(folder: Path) -> None:
    scores = []
    for sim in ("sim_s.csv", "sim_stamped.csv"):
        out = folder / f"{sim}.dtm"
        result = runner.invoke(app, ["fit", "--model", "mechanistic", "--data",
                                     str(folder / "rec.csv"), *CLI, "--mechanistic",
                                     str(folder / sim), "--out", str(out), "--json"])  # fmt: skip
        assert result.exit_code == 0, result.output
        scores.append(result.output[result.output.index("{") :])
        assert out.exists()
    assert scores[0] == scores[1].replace("sim_stamped.csv", "sim_s.csv")


def test_a_stamped_file_of_another_day_is_refused_naming_both_stamps(folder: Path) -> None:
    result = runner.invoke(app, ["fit", "--model", "mechanistic", "--data",
                                 str(folder / "rec.csv"), *CLI, "--mechanistic",
                                 str(folder / "sim_next_day.csv"), "--out",
                                 str(folder / "day.dtm")])  # fmt: skip
    line = " ".join(result.output.split())
    assert result.exit_code == 2 and "Traceback" not in result.output, line
    assert line.startswith(f"error: --mechanistic file {folder / 'sim_next_day.csv'} covers 86400")
    assert "(stamped from 2026-12-02T08:00:00, the record from 2026-12-01T08:00:00)" in line
    assert not (folder / "day.dtm").exists()


def test_a_stamped_file_for_a_record_in_seconds_is_refused(folder: Path) -> None:
    record = dt.read_measurements(folder / "rec_s.csv", **READ)
    physics = dt.MechanisticModel(str(folder / "sim_stamped.csv"))
    with pytest.raises(DataError, match=r"^mechanistic file .*sim_stamped.csv is stamped with "
                                        r"dates \(from 2026-12-01T08:00:00\) but its record "
                                        r".*rec_s.csv is timed in seconds"):  # fmt: skip
        physics.predict_values(record, ("y",))
    result = runner.invoke(app, ["fit", "--model", "mechanistic", "--data",
                                 str(folder / "rec_s.csv"), *CLI, "--mechanistic",
                                 str(folder / "sim_stamped.csv"), "--out",
                                 str(folder / "s.dtm")])  # fmt: skip
    line = " ".join(result.output.split())
    assert result.exit_code == 2 and "--mechanistic file" in line and "fix:" in line, line


def test_a_parquet_timestamp_column_and_a_time_zone_clash(folder: Path, tmp_path: Path) -> None:
    sim = pd.read_csv(folder / "sim_stamped.csv")
    sim["timestamp"] = pd.to_datetime(sim["timestamp"])
    sim.to_parquet(tmp_path / "sim.parquet")
    record = dt.read_measurements(folder / "rec.csv", **READ)
    expected = dt.MechanisticModel(str(folder / "sim_s.csv")).predict_values(record, ("y",))
    got = dt.MechanisticModel(str(tmp_path / "sim.parquet")).predict_values(record, ("y",))
    np.testing.assert_allclose(got, expected, rtol=1e-15, atol=0)
    sim["timestamp"] = sim["timestamp"].dt.tz_localize("Europe/Berlin")
    sim.to_parquet(tmp_path / "sim_tz.parquet")
    with pytest.raises(DataError, match="one has a time zone, the other not"):
        dt.MechanisticModel(str(tmp_path / "sim_tz.parquet")).predict_values(record, ("y",))
