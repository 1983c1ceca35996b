"""Reading and writing measurement files (CSV, Parquet): formats, mapping, time, gaps."""

from __future__ import annotations

import re
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


@pytest.mark.parametrize(("header", "rate_hz"), [("time_ms", 100.0), ("t_min", 1 / 600),
                                                 ("Time_s", 0.1), ("time_sec", 0.1)])  # fmt: skip
def test_time_unit_by_header_suffix(tmp_path: Path, header: str, rate_hz: float) -> None:
    """A millisecond clock named ``time_ms`` was read as seconds (every step 1000x long)."""
    rows = [f"{10 * i},1815,1500,450,355" for i in range(5)]
    path = write_csv(tmp_path / "ms.csv", f"{header},front,second,third,back", rows)
    assert read_measurements(path).sample_rate_hz == pytest.approx(rate_hz)


def test_time_unit_suffix_of_a_named_time_column(tmp_path: Path) -> None:
    rows = [f"{10 * i},1815,1500,450,355" for i in range(5)]
    path = write_csv(tmp_path / "ms.csv", "zeit_ms,front,second,third,back", rows)
    series = read_measurements(path, time_column="zeit_ms")
    assert series.sample_rate_hz == pytest.approx(100.0)
    assert series.time_column == "time"  # its values are seconds now, not the file's


@pytest.mark.parametrize(
    "name", ["time", "t", "time_s", "timestamp", "Time", "Date Time", "date_time"]
)
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


# ------------------------------------------------------------- any machine: outputs, inputs


def tuy_rows(n: int = 8, start: float = 2.5, step: float = 0.001) -> list[str]:
    """A small machine: drive voltage u (V) and position y (m) crossing zero."""
    return [
        f"{start + i * step:.6f},{2.0 * np.sin(i):.6f},{0.004 * np.cos(i) - 0.001:.6f}"
        for i in range(n)
    ]


def test_any_machine_outputs_inputs_and_units(tmp_path: Path) -> None:
    lines = tuy_rows()
    path = write_csv(tmp_path / "tuy.csv", "t,u,y", lines)
    series = read_measurements(path, outputs=["y"], inputs=["u"], units={"y": "m", "u": "V"})
    cells = np.array([[float(c) for c in row.split(",")] for row in lines])
    assert series.channels == ("y",) and list(series.inputs) == ["u"]
    np.testing.assert_array_equal(series.values[:, 0], cells[:, 2])  # no conversion, no check
    np.testing.assert_array_equal(series.inputs["u"], cells[:, 1])
    np.testing.assert_array_equal(series.time_s, cells[:, 0])  # the file's own times
    assert series.units == {"y": "m", "u": "V"}
    assert series.unit("y") == "m" and series.motor_rpm is None
    assert series.metadata["columns"] == {"t": "time", "y": "y", "u": "u"}
    assert series.sample_rate_hz == pytest.approx(1000.0)


def test_undeclared_channel_is_not_checked_as_rpm(tmp_path: Path) -> None:
    path = write_csv(tmp_path / "tuy.csv", "t,u,y", tuy_rows())
    series = read_measurements(path, outputs=["y"], inputs=["u"])
    assert series.unit("y") == "" and series.unit("u") == ""
    assert np.nanmax(np.abs(series.values)) < 0.01  # far below any rpm, yet accepted


def test_units_from_headers_keep_their_spelling(tmp_path: Path) -> None:
    path = write_csv(tmp_path / "tuy.csv", "time [ms],u (V),Y [m]", tuy_rows(start=0, step=1))
    series = read_measurements(path, outputs=["y"], inputs=["u"], units={"y": "m"})
    assert series.units == {"y": "m", "u": "V"}
    assert series.sample_rate_hz == pytest.approx(1000.0)  # ms -> s


def test_outputs_keep_declared_order_and_case(tmp_path: Path) -> None:
    rows = [f"{i * 0.01},{i},{10 + i},{20 + i}" for i in range(4)]
    path = write_csv(tmp_path / "m.csv", "time,Pos_B,pos_a,volts", rows)
    series = read_measurements(path, outputs=["pos_A", "pos_b"], inputs=["Volts"])
    assert series.channels == ("pos_A", "pos_b") and list(series.inputs) == ["Volts"]
    np.testing.assert_array_equal(series.values[:, 0], [10, 11, 12, 13])
    np.testing.assert_array_equal(series.values[:, 1], [0, 1, 2, 3])


def test_mapping_targets_a_declared_output(tmp_path: Path) -> None:
    path = write_csv(tmp_path / "m.csv", "t,drive,position", tuy_rows())
    series = read_measurements(
        path, outputs=["y"], inputs=["u"], columns={"position": "y", "DRIVE": "u"}
    )
    assert series.metadata["columns"] == {"t": "time", "position": "y", "drive": "u"}
    assert series.values[0, 0] == pytest.approx(0.003)


def test_inputs_none_auto_detects_and_empty_means_none(tmp_path: Path) -> None:
    rows = [f"{i * 0.01},1815,1500,450,355,50,256.6" for i in range(4)]
    path = write_csv(tmp_path / "m.csv", "time,front,second,third,back,supply_hz,setpoint_x", rows)
    assert list(read_measurements(path).inputs) == ["supply_hz", "setpoint_x"]
    assert read_measurements(path).units["supply_hz"] == "Hz"
    none = read_measurements(path, inputs=())
    assert none.inputs == {} and none.metadata["ignored_columns"] == ["supply_hz", "setpoint_x"]
    only = read_measurements(path, inputs=["supply_hz"])
    assert list(only.inputs) == ["supply_hz"] and only.metadata["ignored_columns"] == ["setpoint_x"]


def test_rollers_as_declared_outputs_are_still_checked_in_rpm(tmp_path: Path) -> None:
    path = write_csv(
        tmp_path / "r.csv", "time,front,back", [f"{i * 0.01},7.5,5.9" for i in range(4)]
    )
    with pytest.raises(DataError, match="column 'front'.*plausible range"):
        read_measurements(path, outputs=["front", "back"])
    series = read_measurements(
        path, outputs=["front", "back"], units={"front": "rev/s", "back": "rev/s"}
    )
    assert series.units["front"] == "rev/s"


# --------------------------------------------------------------------------------- records


def test_several_files_become_records(tmp_path: Path) -> None:
    a = write_csv(tmp_path / "a.csv", "t,u,y", tuy_rows(n=5, start=0.0))
    b_times = [10.0, 10.001, 10.004, 10.005]  # two rows dropped after the second
    b = write_csv(tmp_path / "b.csv", "t,u,y", [f"{t:.3f},1.0,0.5" for t in b_times])
    series = read_measurements([a, b], outputs=["y"], inputs=["u"], units={"y": "m", "u": "V"})
    assert series.record_starts == (0, 5) and len(series) == 5 + 6
    np.testing.assert_allclose(series.time_s[5:], 10.0 + np.arange(6) * 0.001, atol=1e-12)
    assert np.isnan(series.values[7:9, 0]).all() and series.values[9, 0] == 0.5
    records = series.metadata["records"]
    assert [r["source"] for r in records] == [str(a), str(b)]
    assert [r["time_offset_s"] for r in records] == [0.0, 10.0]
    assert records[1]["inserted_rows"] == 2 and series.metadata["inserted_rows"] == 2
    assert series.metadata["sources"] == [str(a), str(b)]
    parts = list(series.records())
    assert [len(p) for p in parts] == [5, 6] and parts[1].metadata["source"] == str(b)
    assert series.units == {"y": "m", "u": "V"}


def test_record_column_splits_a_file(tmp_path: Path) -> None:
    rows = [f"{r},{t},{1815 + t},1500,450,355" for r, t in [(3, 0), (3, 1), (3, 2), (7, 0), (7, 1)]]
    path = write_csv(tmp_path / "r.csv", "record,time,front,second,third,back", rows)
    series = read_measurements(path)
    assert series.record_starts == (0, 3)
    np.testing.assert_array_equal(series.time_s, [0, 1, 2, 0, 1])  # time restarts per record
    np.testing.assert_array_equal(series.values[:, 0], [1815, 1816, 1817, 1815, 1816])
    recs = series.metadata["records"]
    assert [(r["record"], r["first_row"], r["rows_in_file"]) for r in recs] == [
        (3, 1, 3),
        (7, 4, 2),
    ]
    assert series.metadata["columns"]["record"] == "record"


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_round_trip_with_units_inputs_and_records(tmp_path: Path, suffix: str) -> None:
    rng = np.random.default_rng(3)
    parts = [
        MeasurementSeries(
            time_s=start + np.arange(n) * 0.002,
            values=rng.normal(0.0, 0.01, (n, 2)),
            channels=("x", "y"),
            units={"x": "m", "y": "mm", "u": "V"},
            inputs={"u": rng.normal(0.0, 1.0, n)},
            metadata={"run": k},
        )
        for k, (start, n) in enumerate([(0.0, 7), (0.0, 5), (3.0, 4)])
    ]
    series = MeasurementSeries.concat(parts)
    series.values[2, 1] = np.nan
    path = write_measurements(series, tmp_path / f"m{suffix}")
    units = None if suffix == ".parquet" else {"x": "m", "y": "mm", "u": "V"}
    back = read_measurements(path, outputs=["x", "y"], inputs=["u"], units=units)
    assert back.record_starts == (0, 7, 12) and back.channels == ("x", "y")
    np.testing.assert_array_equal(back.values, series.values)
    np.testing.assert_array_equal(back.time_s, series.time_s)
    np.testing.assert_array_equal(back.inputs["u"], series.inputs["u"])
    assert back.units == {"x": "m", "y": "mm", "u": "V"}
    if suffix == ".parquet":
        with pytest.raises(
            DataError, match="the header gives the unit 'mm' but units declares 'm'"
        ):
            read_measurements(path, outputs=["x", "y"], inputs=["u"], units={"y": "m"})


def test_csv_header_has_plain_names_and_record_column(tmp_path: Path) -> None:
    series = MeasurementSeries.concat([make_series(n=14), make_series(n=13)])
    path = write_measurements(series, tmp_path / "m.csv")
    lines = path.read_text().splitlines()
    assert lines[0] == "time,front,second,third,back,motor,supply_hz,setpoint_delivery,record"
    assert [line.rsplit(",", 1)[1] for line in lines[1:]] == ["0"] * 14 + ["1"] * 13
    back = read_measurements(path)
    assert back.record_starts == (0, 14)
    np.testing.assert_array_equal(back.values, series.values)
    np.testing.assert_array_equal(back.motor_rpm, series.motor_rpm)


def test_parquet_round_trip_of_roller_units(tmp_path: Path) -> None:
    path = write_measurements(make_series(), tmp_path / "m.parquet")
    back = read_measurements(path)
    assert back.units == {
        **dict.fromkeys(ROLLERS, "rpm"),
        "supply_hz": "Hz",
        "setpoint_delivery": "",
    }


def test_write_refuses_clashing_column_names(tmp_path: Path) -> None:
    series = MeasurementSeries(
        np.arange(3.0), np.ones((3, 1)), channels=("y",), inputs={"Y": np.zeros(3)}
    )
    with pytest.raises(DataError, match="two columns would be named 'Y'"):
        write_measurements(series, tmp_path / "m.csv")
    assert list(tmp_path.iterdir()) == []


def test_a_parquet_duration_time_column_is_read_in_seconds(tmp_path: Path) -> None:
    """A timedelta64 column (pandas' durations) was read as nanoseconds taken for seconds:
    '19990000000 s' and '1e-07 Hz', and a model fitted on it."""
    frame = pd.DataFrame({"time": pd.to_timedelta(np.arange(6) * 0.01, unit="s"),
                          "front": 1815.0, "second": 1500.0, "third": 450.0, "back": 355.0})  # fmt: skip
    frame.to_parquet(tmp_path / "td.parquet")
    series = read_measurements(tmp_path / "td.parquet")
    np.testing.assert_allclose(series.time_s, np.arange(6) * 0.01)
    assert series.sample_rate_hz == pytest.approx(100.0)


def test_time_in_msec_by_header_suffix(tmp_path: Path) -> None:
    rows = [f"{10 * i},1815,1500,450,355" for i in range(5)]
    path = write_csv(tmp_path / "ms.csv", "time_msec,front,second,third,back", rows)
    assert read_measurements(path, time_column="time_msec").sample_rate_hz == pytest.approx(100.0)


@pytest.mark.parametrize("cell", ["4847", "1e300"])
def test_a_supply_frequency_no_drive_gives_is_refused(tmp_path: Path, cell: str) -> None:
    """One sample of 4847 Hz (a lost decimal point) moved a calibration without a word."""
    rows = [f"{0.01 * i:.2f},1815,1500,450,355,{cell if i == 3 else '48.47'}" for i in range(6)]
    path = write_csv(tmp_path / "s.csv", "time,front,second,third,back,supply_hz", rows)
    with pytest.raises(DataError, match=r"row 4 \(line 5\), column 'supply_hz': supply "
                                        r"frequency .* Hz is above the 1000 Hz a drive gives"):  # fmt: skip
        read_measurements(path)
    ok = write_csv(tmp_path / "ok.csv", "time,front,second,third,back,supply_hz",
                   [f"{0.01 * i:.2f},1815,1500,450,355,48.47" for i in range(6)])  # fmt: skip
    assert read_measurements(ok).inputs["supply_hz"][0] == pytest.approx(48.47)


@pytest.mark.parametrize("stamps", [False, True])
def test_a_parquet_file_indexed_by_its_time_is_read(tmp_path: Path, stamps: bool) -> None:
    """pandas' to_parquet of a frame indexed by its time: "no time column" (the index was
    dropped), and neither --time-column nor --columns could name it."""
    t = np.arange(6) * 0.01
    index = pd.to_datetime("2024-05-01T08:00:00") + pd.to_timedelta(t, unit="s") if stamps else t
    frame = pd.DataFrame({"front": 1815.0, "second": 1500.0, "third": 450.0, "back": 355.0},
                         index=pd.Index(index, name="time"))  # fmt: skip
    frame.to_parquet(tmp_path / "indexed.parquet")
    series = read_measurements(tmp_path / "indexed.parquet")
    np.testing.assert_allclose(series.time_s, t, atol=1e-9)


def test_a_parquet_file_naming_a_column_twice_is_refused_so(tmp_path: Path) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.table([pa.array(np.arange(6) * 0.01), pa.array(np.full(6, 1815.0)),
                      pa.array(np.full(6, 1816.0))], names=["time", "front", "front"])  # fmt: skip
    pq.write_table(table, tmp_path / "twice.parquet")
    with pytest.raises(DataError, match="the file names column 'front' twice"):
        read_measurements(tmp_path / "twice.parquet")


@pytest.mark.parametrize(("first", "said"), [
    ("sep=,", "the first line 'sep=,' is Excel's separator hint, not a header"),
    ("# logger XYZ, machine FA320A", "the first line '# logger XYZ, machine FA320A' is a comment"),
])  # fmt: skip
def test_a_line_above_the_header_is_named_for_what_it_is(tmp_path: Path, first: str, said: str):
    """Excel's separator hint and a logger's comment lines had read as "7 fields but the
    header has 2" on the next line."""
    path = write_csv(tmp_path / "pre.csv", f"{first}\ntime,front,second,third,back", speed_rows())
    with pytest.raises(DataError, match=re.escape(said)):
        read_measurements(path)


def test_exports_of_other_habits_are_read(tmp_path: Path) -> None:
    """Old-Mac CR line breaks ("the header names column '433.8' twice") and two trailing
    separators ("the header names column '' twice") are read as their rows say."""
    rows = speed_rows()
    cr = tmp_path / "cr.csv"
    cr.write_bytes(("\r".join(["time,front,second,third,back", *rows]) + "\r").encode())
    trailing = write_csv(tmp_path / "tr.csv", "time,front,second,third,back,,",
                         [f"{r},," for r in rows])  # fmt: skip
    for path in (cr, trailing):
        series = read_measurements(path)
        assert len(series) == 6 and series.channels == tuple(ROLLERS)


def test_a_units_row_below_the_header_is_named(tmp_path: Path) -> None:
    path = write_csv(tmp_path / "u.csv", "time,front,second,third,back\ns,rpm,rpm,rpm,rpm",
                     speed_rows())  # fmt: skip
    with pytest.raises(DataError, match="a units row below the header"):
        read_measurements(path)


@pytest.mark.parametrize("clock", ["08:00:00.010", "08:00:01"])
def test_day_first_timestamps_of_a_european_logger_are_read(tmp_path: Path, clock: str) -> None:
    """'01.05.2024 08:00:00.010' (1 May) was refused as no ISO 8601 timestamp."""
    step = 0.01 if "." in clock else 1.0
    stamps = pd.Timestamp("2024-05-01 " + clock) + pd.to_timedelta(np.arange(6) * step, unit="s")
    milli = [f".{t.microsecond // 1000:03d}" if step < 1 else "" for t in stamps]
    rows = [f"{t.strftime('%d.%m.%Y %H:%M:%S')}{m},1815,1500,450,355"
            for t, m in zip(stamps, milli, strict=True)]  # fmt: skip
    path = write_csv(tmp_path / "de.csv", "Datum Zeit,front,second,third,back", rows)
    series = read_measurements(path, time_column="Datum Zeit")
    np.testing.assert_allclose(series.time_s, np.arange(6) * step, atol=1e-6)
    assert series.metadata["start_time"].startswith("2024-05-01T08:00")
