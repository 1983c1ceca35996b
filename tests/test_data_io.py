"""Reading and writing measurement files (CSV, Parquet): formats, mapping, time, gaps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from drafttwin import ROLLERS
from drafttwin.data import MeasurementSeries, read_measurements, write_measurements
from drafttwin.errors import DataError

NOMINAL = np.array([1815.0, 1500.0, 450.0, 355.0])  # rpm, front fastest


def make_series(n: int = 50, rate_hz: float = 100.0, seed: int = 0) -> MeasurementSeries:
    rng = np.random.default_rng(seed)
    rpm = NOMINAL + rng.normal(0.0, 1.0, (n, 4))
    rpm[3, 1] = np.nan
    rpm[10:13, 2] = np.nan
    return MeasurementSeries(
        time_s=np.arange(n) / rate_hz,
        values=rpm,
        motor_rpm=1450.0 + rng.normal(0.0, 0.5, n),
        inputs={"supply_hz": np.full(n, 50.0), "setpoint_delivery": np.full(n, 256.61)},
        metadata={"seed": seed},
    )


def write_csv(path: Path, header: str, rows: list[str]) -> Path:
    path.write_text("\n".join([header, *rows]) + "\n", encoding="utf-8")
    return path


def speed_rows(n: int = 6, step: float = 0.01, start: float = 0.0) -> list[str]:
    return [f"{start + i * step:.6f},1815,1500,450,355" for i in range(n)]


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_round_trip_is_bit_identical(tmp_path: Path, suffix: str) -> None:
    series = make_series()
    path = write_measurements(series, tmp_path / f"m{suffix}")
    back = read_measurements(path)
    np.testing.assert_array_equal(back.values, series.values)  # NaN positions included
    np.testing.assert_array_equal(back.time_s, series.time_s)
    np.testing.assert_array_equal(back.motor_rpm, series.motor_rpm)
    assert set(back.inputs) == {"supply_hz", "setpoint_delivery"}
    np.testing.assert_array_equal(back.inputs["supply_hz"], series.inputs["supply_hz"])
    assert back.channels == ROLLERS
    assert back.metadata["source"] == str(path)
    assert back.metadata["inserted_rows"] == 0
    assert abs(back.sample_rate_hz - 100.0) < 1e-6
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"m{suffix}"]  # no temp files left


def test_csv_writes_gaps_as_empty_cells(tmp_path: Path) -> None:
    path = write_measurements(make_series(), tmp_path / "m.csv")
    lines = path.read_text().splitlines()
    assert lines[0] == "time,front,second,third,back,motor,supply_hz,setpoint_delivery"
    assert lines[4].split(",")[2] == ""  # row 3 (0-based), second roller missing
    assert "nan" not in path.read_text().lower()


def test_parquet_keeps_metadata(tmp_path: Path) -> None:
    path = write_measurements(make_series(seed=7), tmp_path / "m.parquet")
    assert read_measurements(path).metadata["file_metadata"] == {"seed": 7}


def test_write_unsupported_suffix_writes_nothing(tmp_path: Path) -> None:
    with pytest.raises(DataError, match=r"(?s)m\.xlsx.*\.csv or \.parquet"):
        write_measurements(make_series(), tmp_path / "m.xlsx")
    assert list(tmp_path.iterdir()) == []


def test_write_failure_leaves_existing_file_untouched(tmp_path: Path) -> None:
    path = write_measurements(make_series(), tmp_path / "m.csv")
    before = path.read_bytes()
    bad = make_series()
    object.__setattr__(bad, "inputs", {"x": np.zeros(3)})  # wrong length: to_frame fails
    with pytest.raises(ValueError):
        write_measurements(bad, path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["m.csv"]


def test_iso_timestamps_become_seconds_from_start(tmp_path: Path) -> None:
    rows = [f"2024-05-01T08:00:00.{10 * i:03d}Z,1815,1500,450,355" for i in range(5)]
    path = write_csv(tmp_path / "iso.csv", "timestamp,front,second,third,back", rows)
    series = read_measurements(path)
    np.testing.assert_allclose(series.time_s, [0.0, 0.01, 0.02, 0.03, 0.04], atol=1e-12)
    assert series.metadata["start_time"].startswith("2024-05-01T08:00:00")


def test_parquet_datetime_time_column(tmp_path: Path) -> None:
    stamps = pd.date_range("2024-05-01 08:00", periods=5, freq="10ms")
    frame = pd.DataFrame({"time": stamps, **dict(zip(ROLLERS, NOMINAL, strict=True))})
    frame.to_parquet(tmp_path / "dt.parquet")
    series = read_measurements(tmp_path / "dt.parquet")
    np.testing.assert_allclose(series.time_s, np.arange(5) * 0.01, atol=1e-12)
    assert series.metadata["start_time"] == "2024-05-01T08:00:00"


def test_numeric_time_is_kept_as_in_the_file(tmp_path: Path) -> None:
    path = write_csv(tmp_path / "t.csv", "t,front,second,third,back", speed_rows(start=100.0))
    series = read_measurements(path)
    expected = [float(f"{100.0 + i * 0.01:.6f}") for i in range(6)]  # the file's own cells
    np.testing.assert_array_equal(series.time_s, expected)
    assert series.time_s[0] == 100.0
    assert series.metadata["time_offset_s"] == 100.0  # the file's first time value


def test_time_in_milliseconds_by_header_unit(tmp_path: Path) -> None:
    rows = [f"{10 * i},1815,1500,450,355" for i in range(5)]
    path = write_csv(tmp_path / "ms.csv", "time [ms],front,second,third,back", rows)
    assert read_measurements(path).sample_rate_hz == pytest.approx(100.0)


@pytest.mark.parametrize("name", ["time", "t", "time_s", "timestamp", "Time"])
def test_common_time_column_names(tmp_path: Path, name: str) -> None:
    path = write_csv(tmp_path / "t.csv", f"{name},front,second,third,back", speed_rows())
    assert len(read_measurements(path)) == 6


def test_explicit_time_column(tmp_path: Path) -> None:
    path = write_csv(tmp_path / "t.csv", "zeit,front,second,third,back", speed_rows())
    assert len(read_measurements(path, time_column="zeit")) == 6


def test_column_mapping(tmp_path: Path) -> None:
    path = write_csv(tmp_path / "v.csv", "time,v1,v2,v3,v4", speed_rows())
    mapping = {"v1": "front", "v2": "second", "v3": "third", "V4": "back"}
    series = read_measurements(path, columns=mapping)
    np.testing.assert_array_equal(series.values[0], NOMINAL)
    assert series.metadata["columns"]["v1"] == "front"


def test_mapping_can_swap_columns(tmp_path: Path) -> None:
    rows = [f"{i * 0.01},355,1500,450,1815" for i in range(5)]
    path = write_csv(tmp_path / "s.csv", "time,front,second,third,back", rows)
    series = read_measurements(path, columns={"front": "back", "back": "front"})
    np.testing.assert_array_equal(series.column("front"), np.full(5, 1815.0))


def test_headers_with_rpm_units_and_case(tmp_path: Path) -> None:
    header = "Time [s],Front [rpm],second_rpm,THIRD (rpm),back"
    series = read_measurements(write_csv(tmp_path / "u.csv", header, speed_rows()))
    np.testing.assert_array_equal(series.values[-1], NOMINAL)


def test_motor_and_setpoints(tmp_path: Path) -> None:
    rows = [f"{i * 0.01},1815,1500,450,355,1450,50,256.6" for i in range(4)]
    header = "time,front,second,third,back,motor,supply_hz,setpoint_delivery"
    series = read_measurements(write_csv(tmp_path / "m.csv", header, rows))
    np.testing.assert_array_equal(series.motor_rpm, np.full(4, 1450.0))
    assert series.inputs["supply_hz"][0] == 50.0
    assert series.inputs["setpoint_delivery"][0] == 256.6


def test_extra_numeric_column_is_ignored_and_listed(tmp_path: Path) -> None:
    rows = [f"{r},21.5" for r in speed_rows()]
    path = write_csv(tmp_path / "x.csv", "time,front,second,third,back,temperature", rows)
    series = read_measurements(path)
    assert series.metadata["ignored_columns"] == ["temperature"]


def test_text_column_can_be_ignored_by_mapping(tmp_path: Path) -> None:
    rows = [f"{r},ok" for r in speed_rows()]
    path = write_csv(tmp_path / "x.csv", "time,front,second,third,back,note", rows)
    series = read_measurements(path, columns={"note": "ignore"})
    assert series.metadata["ignored_columns"] == ["note"]


def test_missing_cells_become_nan(tmp_path: Path) -> None:
    rows = ["0,1815,1500,450,355", "0.01,,1500,,355", "0.02,1815,NaN,450,355"]
    series = read_measurements(write_csv(tmp_path / "n.csv", "time,front,second,third,back", rows))
    assert np.isnan(series.values).sum() == 3
    assert np.isnan(series.values[1, 0]) and np.isnan(series.values[2, 1])


def test_dropped_rows_are_reinserted_as_missing(tmp_path: Path) -> None:
    times = [0.0, 0.01, 0.04, 0.05, 0.06]  # rows at 0.02 and 0.03 were dropped
    rows = [f"{t},1815,1500,450,355" for t in times]
    series = read_measurements(write_csv(tmp_path / "d.csv", "time,front,second,third,back", rows))
    assert len(series) == 7
    assert series.metadata["inserted_rows"] == 2
    np.testing.assert_allclose(series.time_s, np.arange(7) * 0.01, atol=1e-12)
    assert np.isnan(series.values[2:4]).all() and not np.isnan(series.values[[0, 1, 4, 5, 6]]).any()


def test_small_jitter_is_accepted(tmp_path: Path) -> None:
    times = [0.0, 0.01005, 0.02, 0.02998, 0.04]
    rows = [f"{t},1815,1500,450,355" for t in times]
    series = read_measurements(write_csv(tmp_path / "j.csv", "time,front,second,third,back", rows))
    np.testing.assert_array_equal(series.time_s, times)  # measured times are kept


def test_semicolon_separated_and_bom(tmp_path: Path) -> None:
    rows = [f"{i * 0.01};1815;1500;450;355" for i in range(4)]
    path = tmp_path / "s.csv"
    path.write_bytes(("\ufefftime;front;second;third;back\n" + "\n".join(rows)).encode("utf-8"))
    assert len(read_measurements(path)) == 4


def test_latin1_file(tmp_path: Path) -> None:
    text = "time,front,second,third,back,Drehzahl_\u00fc\n" + "\n".join(
        f"{r},1" for r in speed_rows()
    )
    path = tmp_path / "l.csv"
    path.write_bytes(text.encode("latin-1"))
    assert read_measurements(path).metadata["ignored_columns"] == ["Drehzahl_\u00fc"]


def test_expected_rate_accepted(tmp_path: Path) -> None:
    path = write_csv(tmp_path / "r.csv", "time,front,second,third,back", speed_rows())
    assert len(read_measurements(path, expected_rate_hz=100.0)) == 6


def test_crlf_line_endings(tmp_path: Path) -> None:
    text = "time,front,second,third,back\r\n" + "\r\n".join(speed_rows()) + "\r\n"
    path = tmp_path / "w.csv"
    path.write_bytes(text.encode())
    assert len(read_measurements(path)) == 6


@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    values=hnp.arrays(
        np.float64,
        st.tuples(st.integers(2, 30), st.just(4)),
        elements=st.one_of(
            st.floats(355.0, 5000.0, allow_nan=False, allow_infinity=False),
            st.just(np.nan),
        ),
    ),
    suffix=st.sampled_from([".csv", ".parquet"]),
)
def test_round_trip_property(tmp_path: Path, values: np.ndarray, suffix: str) -> None:
    values[0] = [2000.0, 1500.0, 450.0, 355.0]  # at least one value per column, front fastest
    series = MeasurementSeries(time_s=np.arange(values.shape[0]) * 0.01, values=values)
    back = read_measurements(write_measurements(series, tmp_path / f"p{suffix}"), check_units=False)
    np.testing.assert_array_equal(back.values, values)
