"""A simulator file serves the record it was simulated for, and no other (issue 38, item 3):
the training record's file is refused for a test record, through the CLI and the library
alike, in one line naming both files and the option."""

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
DATA = ["--outputs", "y", "--inputs", "u", "--time-column", "t", "--units", "y=m,u=V"]
TINY = ["--epochs", "1", "--set", "window=8,hidden=4,layers=1", "--quiet"]


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Training and test records, each starting at 0 s (their own time axes) and of other
    lengths, with their own simulator files."""
    path = tmp_path_factory.mktemp("simmatch")
    rng = np.random.default_rng(1)
    for name, n in (("train", 160), ("test", 90)):
        t = np.arange(n) * 0.05
        u = np.repeat(rng.uniform(0.5, 2.0, n // 20 + 1), 20)[:n]
        physics = 1.0 + 0.5 * u
        pd.DataFrame({"t": t, "u": u, "y": physics + rng.normal(0, 0.01, n)}).to_csv(
            path / f"{name}.csv", index=False
        )
        pd.DataFrame({"time": t, "y": physics}).to_csv(path / f"sim_{name}.csv", index=False)
    return path


def _fit(folder: Path, mechanistic: str, *extra: str) -> tuple[int, str]:
    result = runner.invoke(app, ["fit", "--model", "parallel", "--data", str(folder / "train.csv"),
                                 "--test-data", str(folder / "test.csv"), *DATA,
                                 "--mechanistic", mechanistic, "--out",
                                 str(folder / "m.dtm"), *TINY, *extra])  # fmt: skip
    return result.exit_code, result.output


def test_the_training_records_file_is_refused_for_the_test_record(folder: Path) -> None:
    code, out = _fit(folder, str(folder / "sim_train.csv"))
    assert code == 2 and "Traceback" not in out
    line = " ".join(out.split())
    assert line.startswith("error: --mechanistic gives 1 simulator output table(s)")
    assert "sim_train.csv" in line and "train.csv" in line and "test.csv" in line
    assert not (folder / "m.dtm").exists()


def test_a_file_of_another_record_is_refused_by_its_span(folder: Path) -> None:
    # two files, in the wrong order: each spans the other record's time axis
    code, out = _fit(folder, f"{folder / 'sim_test.csv'},{folder / 'sim_train.csv'}")
    line = " ".join(out.split())
    assert code == 2, out
    assert "--mechanistic file" in line and "sim_test.csv covers 0 s to 4.45 s (90 rows)" in line
    assert "its record" in line and "train.csv spans 0 s to 7.95 s (160 rows)" in line


def test_matching_files_fit_and_evaluate_refuses_the_wrong_one(folder: Path) -> None:
    code, out = _fit(folder, f"{folder / 'sim_train.csv'},{folder / 'sim_test.csv'}")
    assert code == 0, out
    wrong = runner.invoke(app, ["evaluate", "--model", str(folder / "m.dtm"), "--test-data",
                                str(folder / "test.csv"), "--time-column", "t",
                                "--mechanistic", str(folder / "sim_train.csv")])  # fmt: skip
    assert wrong.exit_code == 2 and "sim_train.csv covers 0 s to 7.95 s" in " ".join(
        wrong.output.split()
    )


def test_the_library_refuses_alike_naming_the_parameter(folder: Path) -> None:
    read = {"outputs": ["y"], "inputs": ["u"], "time_column": "t", "units": {"y": "m", "u": "V"}}
    train = dt.read_measurements(folder / "train.csv", **read)
    test = dt.read_measurements(folder / "test.csv", **read)
    model = dt.make_model("mechanistic", outputs=("y",))
    physics = dt.MechanisticModel(str(folder / "sim_train.csv"))
    with pytest.raises(DataError, match=r"^mechanistic gives 1 simulator output table"):
        dt.fit_split(model, train, test=test, mechanistic=physics)
    # one record, one file of another record: refused by span
    with pytest.raises(DataError, match="sim_train.csv covers 0 s to 7.95 s"):
        dt.fit_split(model, test, train_fraction=0.5, mechanistic=physics)
    both = dt.MechanisticModel([str(folder / "sim_train.csv"), str(folder / "sim_test.csv")])
    part = dt.fit_split(model, train, test=test, mechanistic=both)
    direct = model.predict_values(
        part.test_part(), dt.MechanisticModel(str(folder / "sim_test.csv"))
    )
    scored = dt.evaluate(model, part, mechanistic=both)
    assert np.allclose(scored.predictions["y"].to_numpy(), direct[:, 0])


def test_a_chronological_split_of_two_records_is_scored_on_the_last_records_tables(
    folder: Path,
) -> None:
    """Two records with their simulator files, split chronologically: the test part is the
    tail of the second record, which runs free on the second file (evaluate refused every
    way of giving the files before: 2 tables for its 1 record). The physics alone scores
    what the second file's tail gives, computed here by hand."""
    from drafttwin.evaluation.protocol import evaluate

    ch = {"outputs": ["y"], "inputs": ["u"], "units": {"y": "m", "u": "V"}, "time_column": "t"}
    both = dt.read_measurements([folder / "train.csv", folder / "test.csv"], **ch)
    files = f"{folder / 'sim_train.csv'},{folder / 'sim_test.csv'}"
    model = dt.make_model("mechanistic", task="simulation", init_samples=5)
    part = dt.fit_split(model, both, mechanistic=dt.MechanisticModel.from_option(files))
    assert part.mode == "chronological" and part.test_part().n_records == 1
    result = evaluate(model, part, mechanistic=dt.MechanisticModel.from_option(files))
    test = pd.read_csv(folder / "test.csv").tail(len(part.test_part()))
    sim = pd.read_csv(folder / "sim_test.csv").set_index("time").loc[test["t"], "y"].to_numpy()
    err = (test["y"].to_numpy() - sim)[5:]  # after the test part's initialisation rows
    assert result.metrics["y"].rmse == pytest.approx(np.sqrt(np.mean(err**2)), rel=1e-9)
    # the files as text, as dt.fit takes them (a path "a,b" not found before), on the series
    text = dt.evaluate(model, both, mechanistic=files)
    assert text.metrics["y"].rmse == result.metrics["y"].rmse


def test_the_physics_alone_reads_its_simulator_file_at_fit(folder: Path, tmp_path: Path) -> None:
    """``fit --model mechanistic`` trains nothing, and read no simulator file without
    --test-data: a file without the output's column was accepted and a model file written,
    refused only by a later evaluate."""
    pd.read_csv(folder / "sim_train.csv").rename(columns={"y": "z"}).to_csv(
        tmp_path / "sim_z.csv", index=False
    )
    out = tmp_path / "m.dtm"
    result = runner.invoke(app, ["fit", "--model", "mechanistic", "--data",
                                 str(folder / "train.csv"), *DATA, "--mechanistic",
                                 str(tmp_path / "sim_z.csv"), "--out", str(out), "--quiet"])  # fmt: skip
    line = " ".join(result.output.split())
    assert result.exit_code == 2 and "sim_z.csv" in line and "no column(s) ['y']" in line
    assert not out.exists()


def test_a_simulator_file_passes_the_data_layers_file_checks(folder: Path, tmp_path: Path) -> None:
    """A binary file, an empty file or a folder given as --mechanistic: one line naming it and
    the option, with a fix (before: "cannot read the file ('utf-8' codec can't decode ...)"
    without a fix, and a folder "file not found")."""
    (tmp_path / "junk.csv").write_bytes(bytes(range(256)) * 8)
    (tmp_path / "empty.csv").write_bytes(b"")
    (tmp_path / "folder").mkdir()
    for name, said in (("junk.csv", "binary content"), ("empty.csv", "file is empty"),
                       ("folder", "a folder")):  # fmt: skip
        result = runner.invoke(app, ["fit", "--model", "mechanistic", "--data",
                                     str(folder / "train.csv"), *DATA, "--mechanistic",
                                     str(tmp_path / name), "--out", str(tmp_path / "m.dtm"),
                                     "--quiet"])  # fmt: skip
        line = " ".join(result.output.split())
        assert result.exit_code == 2 and said in line and "--mechanistic" in line, line
        assert "fix:" in line and "Traceback" not in result.output


def _renamed(folder: Path, name: str, time_header: str, scale: float = 1.0) -> Path:
    frame = pd.read_csv(folder / f"{name}.csv")
    frame = frame.rename(columns={"t": time_header, "time": time_header})
    frame[time_header] = frame[time_header] * scale
    path = folder / f"{time_header}_{name}.csv"
    frame.to_csv(path, index=False)
    return path


def test_the_simulator_file_takes_the_records_time_column_name(folder: Path) -> None:
    """``--time-column zeit`` named the record's time column, and the simulator file with the
    same column was refused ("no time column (looked for time, time_s, t)")."""
    data = [_renamed(folder, n, "zeit") for n in ("train", "test", "sim_train", "sim_test")]
    args = ["fit", "--model", "mechanistic", "--data", str(data[0]), "--test-data", str(data[1]),
            "--outputs", "y", "--inputs", "u", "--units", "y=m,u=V", "--time-column", "zeit",
            "--mechanistic", f"{data[2]},{data[3]}", "--out", str(folder / "zeit.dtm")]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert (folder / "zeit.dtm").exists()
    # without --time-column the record is refused first; a simulator file without any time
    # column names the option that would name it
    read = {"outputs": ["y"], "inputs": ["u"], "time_column": "zeit", "units": {"y": "m", "u": "V"}}
    record = dt.read_measurements(data[0], **read)
    physics = dt.MechanisticModel([str(data[2])], time_column="zeit")
    np.testing.assert_allclose(physics.predict_values(record, ("y",))[:, 0],
                               pd.read_csv(data[2])["y"].to_numpy())  # fmt: skip
    other = _renamed(folder, "sim_test", "uhrzeit")
    with pytest.raises(DataError, match="or zeit as time_column names it"):
        dt.MechanisticModel([str(other)], time_column="zeit")
    refused = runner.invoke(app, [*args[:-4], "--mechanistic", str(other), "--out",
                                  str(folder / "other.dtm")])  # fmt: skip
    assert refused.exit_code == 2 and "or zeit as --time-column names it" in " ".join(
        refused.output.split()
    ), refused.output


def test_a_simulator_file_in_milliseconds_is_read_in_seconds(folder: Path) -> None:
    sim_ms = _renamed(folder, "sim_train", "time_ms", scale=1000.0)
    read = {"outputs": ["y"], "inputs": ["u"], "time_column": "t", "units": {"y": "m", "u": "V"}}
    record = dt.read_measurements(folder / "train.csv", **read)
    got = dt.MechanisticModel([str(sim_ms)]).predict_values(record, ("y",))[:, 0]
    np.testing.assert_allclose(got, pd.read_csv(folder / "sim_train.csv")["y"].to_numpy())


def test_a_simulator_file_in_milliseconds_under_time_is_named_so(folder: Path) -> None:
    """ "covers 0 s to 7950 s ... the simulator output of another record" gave no hint that
    the file counts milliseconds."""
    frame = pd.read_csv(folder / "sim_train.csv")
    frame["time"] = frame["time"] * 1000.0
    frame.to_csv(folder / "sim_ms.csv", index=False)
    read = {"outputs": ["y"], "inputs": ["u"], "time_column": "t", "units": {"y": "m", "u": "V"}}
    record = dt.read_measurements(folder / "train.csv", **read)
    physics = dt.MechanisticModel([str(folder / "sim_ms.csv")])
    with pytest.raises(DataError, match=r"its time column is in ms \(its span is 1000 x the "
                                        r"data's\): name it 'time \[ms\]'"):  # fmt: skip
        physics.match_records(record)  # as fit, evaluate and predict check it


def test_a_simulator_file_one_step_off_its_record_is_noted(folder: Path) -> None:
    """A file starting one step after its record (0.05-8.0 s for 0-7.95 s) was taken
    without a word; read at the record's times it moves the physics by a step (31 % of a
    speed change's RMSE in a helper's try). Accepted (a simulator may stamp either end of a
    step), and said."""
    frame = pd.read_csv(folder / "sim_train.csv")
    frame["time"] = frame["time"] + 0.05
    frame.to_csv(folder / "sim_late.csv", index=False)
    args = ["fit", "--model", "mechanistic", "--data", str(folder / "train.csv"), *DATA,
            "--mechanistic", str(folder / "sim_late.csv"), "--out", str(folder / "late.dtm")]  # fmt: skip
    result = runner.invoke(app, args)
    said = " ".join(result.output.split())
    assert result.exit_code == 0, said
    assert (
        f"note: --mechanistic file {folder / 'sim_late.csv'} starts 0.05 s after its record" in said
    )
    assert "shift its time column by that step" in said
    aligned = runner.invoke(app, [*args[:-3], str(folder / "sim_train.csv"), "--out",
                                  str(folder / "aligned.dtm")])  # fmt: skip
    assert aligned.exit_code == 0 and "starts 0.05 s" not in aligned.output
