"""Mechanistic sources: simulator files on the data's own time axis, record by record; tables,
arrays, callables (with inputs), drive trains; every refusal names what is wrong."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from drafttwin.cli import app
from drafttwin.data.io import read_measurements
from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import ConfigError, DataError
from drafttwin.models import MechanisticModel

from ._synthetic import mechanistic

ROLLERS = ("front", "second", "third", "back")


def _sim_frame(time_s: np.ndarray) -> pd.DataFrame:
    mech = mechanistic(time_s)
    return pd.DataFrame({"time": time_s, **{r: mech[:, j] for j, r in enumerate(ROLLERS)}})


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_file_source_is_interpolated_onto_the_grid(suffix: str, series, tmp_path: Path) -> None:
    coarse = np.arange(0, series.time_s[-1] + 0.05, 0.05)
    frame = _sim_frame(coarse)
    path = tmp_path / f"sim{suffix}"
    frame.to_parquet(path) if suffix == ".parquet" else frame.to_csv(path, index=False)
    got = MechanisticModel(path).predict_values(series)
    want = np.column_stack([np.interp(series.time_s, coarse, frame[r]) for r in ROLLERS])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    # any subset of channels, by name, in the order asked
    np.testing.assert_allclose(MechanisticModel(path).predict_values(series, ["back", "front"]),
                               want[:, [3, 0]], atol=1e-9)  # fmt: skip


def test_drafttwin_simulate_output_is_a_source_for_data_on_the_same_time_axis(tmp_path) -> None:
    """`drafttwin simulate` stamps each interval mean at its end (0.01, 0.02, ...): a file read
    with the same stamps lines up exactly (this used to be refused as not covering)."""
    sim = tmp_path / "sim.csv"
    result = CliRunner().invoke(app, ["simulate", "--duration", "1", "--rate", "100", "--quiet",
                                      "--out", str(sim)])  # fmt: skip
    assert result.exit_code == 0, result.output
    frame = pd.read_csv(sim)
    assert frame["time"].iloc[0] == pytest.approx(0.01)
    frame[["time", *ROLLERS]].to_csv(tmp_path / "measured.csv", index=False)
    data = read_measurements(tmp_path / "measured.csv")
    assert data.time_s[0] == pytest.approx(0.01)
    got = MechanisticModel(sim).predict_values(data)
    np.testing.assert_allclose(got, frame[list(ROLLERS)].to_numpy(), rtol=0, atol=1e-9)


def test_one_step_beyond_the_table_is_held_further_is_refused(series, tmp_path: Path) -> None:
    """A simulator may stamp an interval at its start or its end: one of its steps beyond
    either end is held at the edge value; more is refused, naming both spans."""
    step = 0.01
    late = tmp_path / "late.csv"
    _sim_frame(series.time_s + step).to_csv(late, index=False)  # starts one step late
    got = MechanisticModel(late).predict_values(series)
    np.testing.assert_allclose(got[0], mechanistic(series.time_s[:1] + step)[0], atol=1e-9)
    later = tmp_path / "later.csv"
    _sim_frame(series.time_s + 2.5 * step).to_csv(later, index=False)
    with pytest.raises(DataError, match=r"covers 0.025 s to 2.015 s but the data span 0 s"):
        MechanisticModel(later).predict_values(series)


def test_file_source_not_covering_the_span_is_refused(series, tmp_path: Path) -> None:
    path = tmp_path / "short.csv"
    _sim_frame(np.arange(0, 1.0, 0.01)).to_csv(path, index=False)
    with pytest.raises(DataError, match="covers 0 s to 0.99 s") as err:
        MechanisticModel(path).predict_values(series)
    assert str(path) in str(err.value)


def test_file_source_problems_are_named(series, tmp_path: Path) -> None:
    bad = tmp_path / "bad.csv"
    rows = "".join(f"{0.01 * k:.2f},1,{'x' if k == 5 else 2},3,4\n" for k in range(300))
    bad.write_text("time,front,second,third,back\n" + rows)
    with pytest.raises(DataError, match=r"row 6 \(line 7\), column 'second'"):
        MechanisticModel(bad).predict_values(series)
    back = tmp_path / "back.csv"
    back.write_text("time,front,second,third,back\n0,1,2,3,4\n0,1,2,3,4\n")
    with pytest.raises(DataError, match="not strictly increasing"):
        MechanisticModel(back)
    no_time = tmp_path / "nt.csv"
    no_time.write_text("front,second,third,back\n1,2,3,4\n1,2,3,4\n")
    with pytest.raises(DataError, match="no time column"):
        MechanisticModel(no_time)
    with pytest.raises(DataError, match="file not found"):
        MechanisticModel(tmp_path / "missing.csv")
    two = tmp_path / "two.csv"
    _sim_frame(series.time_s)[["time", "front", "back"]].to_csv(two, index=False)
    with pytest.raises(DataError, match=r"no column\(s\) \['second', 'third'\]"):
        MechanisticModel(two).predict_values(series)


def test_column_mapping(series) -> None:
    frame = _sim_frame(series.time_s).rename(columns={"front": "v1", "back": "v4"})
    model = MechanisticModel(frame, columns={"front": "v1", "back": "v4"})
    np.testing.assert_allclose(model.predict_values(series), mechanistic(series.time_s), atol=1e-9)


def test_array_and_callable_sources_are_checked(series) -> None:
    arr = mechanistic(series.time_s)
    np.testing.assert_array_equal(MechanisticModel(arr).predict_values(series), arr)
    with pytest.raises(DataError, match="rows but the series has"):
        MechanisticModel(arr[:-1]).predict_values(series)
    with pytest.raises(DataError, match="shape"):
        MechanisticModel(lambda t: np.zeros((len(t), 3))).predict_values(series)
    with pytest.raises(DataError, match="finite"):
        MechanisticModel(lambda t: np.full((len(t), 4), np.nan)).predict_values(series)
    with pytest.raises(DataError, match="cannot use"):
        MechanisticModel(42)


def test_a_callable_may_take_the_records_inputs(series) -> None:
    u = np.linspace(0.0, 1.0, len(series))
    with_u = MeasurementSeries(series.time_s, series.values, inputs={"u": u})
    seen = []

    def physics(time_s: np.ndarray, inputs: dict[str, np.ndarray]) -> pd.DataFrame:
        seen.append(inputs["u"].copy())
        return pd.DataFrame({r: 100.0 * inputs["u"] + k for k, r in enumerate(ROLLERS)})

    got = MechanisticModel(physics).predict_values(with_u)
    np.testing.assert_allclose(got[:, 2], 100.0 * u + 2)
    np.testing.assert_array_equal(seen[0], u)


def test_sources_run_record_by_record(series, tmp_path: Path) -> None:
    """Every record on its own time axis: one file per record, or one file whose `record`
    column splits it (as `drafttwin predict` writes several records)."""
    a, b = series.slice(0, 100), series.slice(100)
    b = MeasurementSeries(b.time_s - b.time_s[0], b.values)  # the second record restarts at 0
    two = MeasurementSeries.concat([a, b])
    files = []
    for k, part in enumerate((a, b)):
        files.append(tmp_path / f"r{k}.csv")
        _sim_frame(part.time_s).to_csv(files[-1], index=False)
    want = np.vstack([mechanistic(a.time_s), mechanistic(b.time_s)])
    np.testing.assert_allclose(MechanisticModel(files).predict_values(two), want, atol=1e-9)
    both = pd.concat([pd.read_csv(f).assign(record=k + 1) for k, f in enumerate(files)])
    both.to_csv(tmp_path / "both.csv", index=False)
    np.testing.assert_allclose(MechanisticModel(tmp_path / "both.csv").predict_values(two), want,
                               atol=1e-9)  # fmt: skip
    with pytest.raises(DataError, match=r"gives 2 simulator output table\(s\) .* for 3 records"):
        MechanisticModel(files).predict_values(MeasurementSeries.concat([a, b, b]))
    with pytest.raises(DataError, match=r"gives 1 simulator output table\(s\) .* for 2 records"):
        MechanisticModel(files[0]).predict_values(two)  # one record's file: never reused
    calls = []
    MechanisticModel(lambda t: calls.append(t[0]) or mechanistic(t)).predict_values(two)
    assert calls == [a.time_s[0], 0.0]


def test_command_line_sources(tmp_path: Path) -> None:
    assert MechanisticModel.from_option("preset").spec() == {"kind": "preset", "name": "fa320a"}
    assert MechanisticModel.from_option("preset:fa320a").name == "preset fa320a"
    belt = Path(__file__).resolve().parents[1] / "docs" / "examples" / "belt_drive.toml"
    source = MechanisticModel.from_option(f"config:{belt}")
    assert source.spec()["kind"] == "train" and source.required_inputs() == ("u",)
    with pytest.raises(ConfigError, match="config: needs a file"):
        MechanisticModel.from_option("config:")
    with pytest.raises(DataError, match="file not found"):
        MechanisticModel.from_option(f"{tmp_path / 'a.csv'},{tmp_path / 'b.csv'}")


def test_a_preset_follows_the_recorded_set_point() -> None:
    """The FA320A preset as a source tracks a start-up recorded by the plant (the plant has
    the true parameters and its own disturbances, so the error is not zero: it is small)."""
    from drafttwin.plant.emulator import Plant

    rec = Plant().run(12.0, rate_hz=100.0, seed=5, scenario="startup")
    physics = MechanisticModel.from_preset("fa320a").predict_values(rec.series)
    err = physics - rec.true_rpm
    running = rec.true_rpm[-100:].mean(axis=0)
    assert np.all(np.sqrt(np.mean(err**2, axis=0)) < 0.002 * running)
    assert np.abs(physics[:90]).max() < 1e-6  # standing still before the ramp starts at 1 s
