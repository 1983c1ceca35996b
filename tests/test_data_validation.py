"""Every refusal of a measurement file: a DataError naming file, place and fix; nothing written."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from drafttwin import ROLLERS
from drafttwin.data import MeasurementSeries, chronological_split, read_measurements
from drafttwin.errors import ConfigError, DataError

HEADER = "time,front,second,third,back"


def rows(n: int = 6, step: float = 0.01, speeds: str = "1815,1500,450,355") -> list[str]:
    return [f"{i * step:.6f},{speeds}" for i in range(n)]


def csv(tmp_path: Path, lines: list[str], name: str = "m.csv") -> Path:
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def refuse(path: Path, *places: str, paths: list[Path] | None = None, **kwargs: object) -> str:
    """Read ``path`` (or ``paths`` as records), expect a DataError; check it names the file
    ``path`` and ``places``."""
    before = sorted(p.name for p in path.parent.iterdir())
    with pytest.raises(DataError) as info:
        read_measurements(paths or path, **kwargs)  # type: ignore[arg-type]
    message = info.value.message
    assert str(path) in message
    for place in places:
        assert place in message, f"{place!r} not in {message!r}"
    assert "fix:" in message
    assert sorted(p.name for p in path.parent.iterdir()) == before  # nothing written
    return message


# ------------------------------------------------------------------------------- the file


def test_file_missing(tmp_path: Path) -> None:
    refuse(tmp_path / "nope.csv", "file not found")


def test_empty_file(tmp_path: Path) -> None:
    path = tmp_path / "empty.csv"
    path.write_bytes(b"")
    refuse(path, "file is empty")


def test_blank_lines_only(tmp_path: Path) -> None:
    refuse(csv(tmp_path, ["", "  "]), "no header")


def test_header_without_rows(tmp_path: Path) -> None:
    refuse(csv(tmp_path, [HEADER]), "no data rows")


def test_single_row(tmp_path: Path) -> None:
    refuse(csv(tmp_path, [HEADER, *rows(1)]), "only one data row")


def test_unsupported_suffix(tmp_path: Path) -> None:
    path = tmp_path / "m.xlsx"
    path.write_bytes(b"PK\x03\x04")
    refuse(path, "unsupported file type '.xlsx'", ".csv or .parquet")


def test_folder_instead_of_file(tmp_path: Path) -> None:
    (tmp_path / "dir.csv").mkdir()
    refuse(tmp_path / "dir.csv", "a folder")


def test_a_device_is_named_so(tmp_path: Path) -> None:
    """/dev/null had been called "not a file (a folder?)"."""
    refuse(Path("/dev/null"), "a device or pipe, not a file")


def test_binary_content_in_csv(tmp_path: Path) -> None:
    path = tmp_path / "bin.csv"
    path.write_bytes(b"PAR1\x00\x01\x02\x00garbage")
    refuse(path, "binary content")


def test_broken_parquet(tmp_path: Path) -> None:
    path = tmp_path / "m.parquet"
    path.write_text(HEADER + "\n" + "\n".join(rows()))
    refuse(path, "cannot be read as Parquet")


# ---------------------------------------------------------------------------- the columns


def test_no_time_column(tmp_path: Path) -> None:
    msg = refuse(csv(tmp_path, ["when,front,second,third,back", *rows()]), "no time column")
    assert "columns: when, front" in msg and "--columns mytime=time" in msg


def test_missing_roller_columns_suggests_mapping(tmp_path: Path) -> None:
    msg = refuse(csv(tmp_path, ["time,v1,v2,v3,v4", *rows()]), "columns: time, v1, v2, v3, v4")
    assert "missing roller columns: front, second, third, back" in msg
    assert "--columns v1=front,v2=second,v3=third,v4=back" in msg


def test_one_roller_missing(tmp_path: Path) -> None:
    lines = ["time,front,second,third", *[f"{i * 0.01},1815,1500,450" for i in range(4)]]
    assert "missing roller column: back" in refuse(csv(tmp_path, lines), "columns:")


def test_all_missing_column(tmp_path: Path) -> None:
    lines = [HEADER, *[f"{i * 0.01},1815,1500,,355" for i in range(5)]]
    refuse(csv(tmp_path, lines), "column 'third'", "no values")


def test_extra_text_column(tmp_path: Path) -> None:
    lines = [HEADER + ",note", *[f"{r},hello" for r in rows()]]
    msg = refuse(csv(tmp_path, lines), "column 'note'", "non-numeric column")
    assert "--columns 'note'=ignore" in msg


def test_duplicate_header(tmp_path: Path) -> None:
    lines = [HEADER + ",front", *[f"{r},1" for r in rows()]]
    refuse(csv(tmp_path, lines), "line 1 (header)", "'front' twice")


def test_two_columns_for_one_role(tmp_path: Path) -> None:
    lines = [
        "time,t,front,second,third,back",
        *[f"{i * 0.01},{i},1815,1500,450,355" for i in range(4)],
    ]
    refuse(csv(tmp_path, lines), "column 't'", "two columns give 'time'")


def test_mapping_names_absent_column(tmp_path: Path) -> None:
    refuse(
        csv(tmp_path, [HEADER, *rows()]),
        "--columns",
        "'v9' is not in the file",
        columns={"v9": "front"},
    )


def test_mapping_to_unknown_target(tmp_path: Path) -> None:
    refuse(
        csv(tmp_path, [HEADER, *rows()]),
        "--columns",
        "unknown target 'fourth'",
        columns={"back": "fourth"},
    )


def test_unit_in_header(tmp_path: Path) -> None:
    lines = ["time,front [rad/s],second,third,back", *rows()]
    msg = refuse(csv(tmp_path, lines), "column 'front [rad/s]'", "in rad/s")
    assert "9.5493" in msg


def test_unknown_time_unit(tmp_path: Path) -> None:
    refuse(csv(tmp_path, ["time [h],front,second,third,back", *rows()]), "unknown time unit 'h'")


# ---------------------------------------------------------------------------- the layout


def test_row_with_too_many_fields(tmp_path: Path) -> None:
    lines = [HEADER, *rows(3), "0.03,1815,1500,450,355,7", *rows(2)]
    refuse(csv(tmp_path, lines), "row 4 (line 5)", "6 fields but the header has 5")


def test_row_with_too_few_fields(tmp_path: Path) -> None:
    lines = [HEADER, *rows(2), "0.02,1815,1500", *rows(2)]
    refuse(csv(tmp_path, lines), "row 3 (line 4)", "3 fields but the header has 5")


def test_extra_and_missing_field_that_balance_out(tmp_path: Path) -> None:
    lines = [HEADER, *rows(2), "0.02,1815,1500,450,355,9", "0.03,1815,1500,450", *rows(1)]
    refuse(csv(tmp_path, lines), "row 3 (line 4)", "6 fields")


# ------------------------------------------------------------------------------ the values


def test_non_numeric_cell(tmp_path: Path) -> None:
    lines = [HEADER, *rows(4), "0.04,1815,1500,abc,355"]
    refuse(csv(tmp_path, lines), "row 5 (line 6), column 'third'", "non-numeric value 'abc'")


def test_row_numbers_skip_blank_lines(tmp_path: Path) -> None:
    lines = [HEADER, "0,1815,1500,450,355", "", "0.01,1815,oops,450,355"]
    refuse(csv(tmp_path, lines), "row 2 (line 4), column 'second'")


def test_decimal_comma_hint(tmp_path: Path) -> None:
    lines = ["time;front;second;third;back", "0;1815;1500;450;355", "0.01;1815,5;1500;450;355"]
    refuse(csv(tmp_path, lines), "row 2 (line 3), column 'front'", "decimal comma")
    # a European export's time column shows it first
    lines = ["time;front;second;third;back", "0;1815;1500;450;355", "0,01;1815,5;1500;450;355"]
    refuse(csv(tmp_path, lines), "row 2 (line 3), column 'time'", "decimal comma")


def test_infinite_value(tmp_path: Path) -> None:
    lines = [HEADER, *rows(2), "0.02,inf,1500,450,355"]
    refuse(csv(tmp_path, lines), "row 3 (line 4), column 'front'", "infinite value 'inf'")


def test_parquet_rows_are_named(tmp_path: Path) -> None:
    import pandas as pd

    frame = pd.DataFrame(
        {"time": [0.0, 0.01, 0.01], **{r: [1815.0, 1500.0, 450.0] for r in ROLLERS}}
    )
    frame.to_parquet(tmp_path / "p.parquet")
    refuse(tmp_path / "p.parquet", "row 3", "duplicate time stamp")


# -------------------------------------------------------------------------------- the time


def test_time_goes_backwards(tmp_path: Path) -> None:
    lines = [HEADER, "0,1815,1500,450,355", "0.02,1815,1500,450,355", "0.01,1815,1500,450,355"]
    refuse(csv(tmp_path, lines), "row 3 (line 4)", "time goes backwards", "sort the rows")


def test_duplicate_timestamp(tmp_path: Path) -> None:
    lines = [HEADER, *rows(3), "0.02,1815,1500,450,355", "0.03,1815,1500,450,355"]
    refuse(csv(tmp_path, lines), "row 4 (line 5)", "duplicate time stamp (same time as row 3")


def test_empty_time_cell(tmp_path: Path) -> None:
    lines = [HEADER, *rows(2), ",1815,1500,450,355"]
    refuse(csv(tmp_path, lines), "row 3 (line 4), column 'time'", "empty time cell")


def test_bad_timestamp(tmp_path: Path) -> None:
    lines = [
        "timestamp,front,second,third,back",
        "2024-05-01T08:00:00.000,1,2,3,4",
        "yesterday,1,2,3,4",
    ]
    refuse(csv(tmp_path, lines), "row 2 (line 3), column 'timestamp'", "'yesterday'")


def test_text_in_numeric_time_column(tmp_path: Path) -> None:
    lines = [HEADER, *rows(2), "abc,1815,1500,450,355", "0.03,1815,1500,450,355"]
    refuse(csv(tmp_path, lines), "row 3 (line 4), column 'time'", "time value 'abc'")


def test_mixed_time_zones_are_accepted(tmp_path: Path) -> None:
    stamps = [
        "2024-05-01T08:00:00+02:00",
        "2024-05-01T06:00:00.01Z",
        "2024-05-01T08:00:00.02+02:00",
    ]
    path = csv(
        tmp_path, ["timestamp,front,second,third,back", *[f"{s},1815,1500,450,355" for s in stamps]]
    )
    np.testing.assert_allclose(read_measurements(path).time_s, [0.0, 0.01, 0.02], atol=1e-12)


def test_irregular_sampling(tmp_path: Path) -> None:
    times = [0.0, 0.01, 0.02, 0.035, 0.045, 0.055, 0.065]
    lines = [HEADER, *[f"{t},1815,1500,450,355" for t in times]]
    refuse(csv(tmp_path, lines), "row 4 (line 5)", "not a whole multiple of the sampling step")


def test_wrong_rate_with_millisecond_hint(tmp_path: Path) -> None:
    lines = [HEADER, *[f"{10 * i},1815,1500,450,355" for i in range(5)]]
    msg = refuse(csv(tmp_path, lines), "time column", "expected 100 Hz", expected_rate_hz=100.0)
    assert "milliseconds" in msg


def test_joined_recordings(tmp_path: Path) -> None:
    lines = [HEADER, *rows(3), "3600,1815,1500,450,355"]
    refuse(csv(tmp_path, lines), "row 4 (line 5)", "joined together")


# ------------------------------------------------------------------------------ the units


def test_rev_or_rad_per_second(tmp_path: Path) -> None:
    msg = refuse(csv(tmp_path, [HEADER, *rows(speeds="30.2,25,7.5,5.9")]), "column 'third'")
    assert "rev/s" in msg and "rad/s" in msg and "--no-unit-check" in msg


def test_implausibly_fast(tmp_path: Path) -> None:
    refuse(
        csv(tmp_path, [HEADER, *rows(speeds="190000,1500,450,355")]),
        "column 'front'",
        "encoder counts",
    )


def test_front_slower_than_back(tmp_path: Path) -> None:
    msg = refuse(
        csv(tmp_path, [HEADER, *rows(speeds="355,450,1500,1815")]), "columns 'front', 'back'"
    )
    assert "swapped" in msg and "--columns front=back,back=front" in msg


def test_rad_per_second_against_nominal(tmp_path: Path) -> None:
    path = csv(tmp_path, [HEADER, *rows(speeds="190.1,157,47.1,37.2")])
    nominal = {"front": 1815.0, "second": 1500.0, "third": 450.0, "back": 355.0}
    refuse(path, "column 'front'", "matches a column in rad/s", nominal_rpm=nominal)


def test_surface_speed_against_nominal(tmp_path: Path) -> None:
    path = csv(tmp_path, [HEADER, *rows(speeds="256.6,165,49.5,39.1")])
    kwargs = {"nominal_rpm": {"front": 1815.0}, "diameters_mm": {"front": 45.0}}
    refuse(path, "column 'front'", "m/min", **kwargs)


def test_unit_check_can_be_switched_off(tmp_path: Path) -> None:
    path = csv(tmp_path, [HEADER, *rows(speeds="30.2,25,7.5,5.9")])
    assert len(read_measurements(path, check_units=False)) == 6


def test_standstill_file_passes_unit_check(tmp_path: Path) -> None:
    assert len(read_measurements(csv(tmp_path, [HEADER, *rows(speeds="0,0,0,0")]))) == 6


def test_negative_running_speed(tmp_path: Path) -> None:
    path = csv(tmp_path, [HEADER, *rows(speeds="-1815,-1500,-450,-355")])
    msg = refuse(path, "column 'front'", "running speed is negative", "flip the sign")
    assert "-1815 rpm" in msg


def test_output_declared_rpm_with_implausible_values(tmp_path: Path) -> None:
    lines = ["t,u,y", *[f"{i * 0.01},{i % 3},{0.002 + 0.001 * (i % 2)}" for i in range(6)]]
    path = csv(tmp_path, lines)
    refuse(
        path,
        "column 'y'",
        "plausible range 10-10000 rpm",
        outputs=["y"],
        inputs=["u"],
        units={"y": "rpm"},
    )
    assert read_measurements(path, outputs=["y"], inputs=["u"]).unit("y") == ""  # undeclared


def test_header_unit_contradicts_declared_unit(tmp_path: Path) -> None:
    lines = ["t,u [V],y [mm]", *[f"{i * 0.01},1,{i}" for i in range(4)]]
    msg = refuse(
        csv(tmp_path, lines),
        "column 'y [mm]'",
        outputs=["y"],
        inputs=["u"],
        units={"y": "m", "u": "V"},
    )
    assert "the header gives the unit 'mm' but units declares 'm' for 'y'" in msg


def test_named_column_in_another_unit_than_its_name(tmp_path: Path) -> None:
    lines = ["time,front,second,third,back,supply_hz [rpm]", *[f"{r},50" for r in rows()]]
    refuse(csv(tmp_path, lines), "column 'supply_hz [rpm]'", "'supply_hz' is in Hz by name")


def test_explicit_input_missing(tmp_path: Path) -> None:
    lines = ["t,y,volts", *[f"{i * 0.01},{i},1" for i in range(4)]]
    msg = refuse(
        csv(tmp_path, lines),
        "columns: t, y, volts",
        "missing input column: u",
        outputs=["y"],
        inputs=["u"],
    )
    assert "--columns volts=u" in msg


def test_explicit_output_missing(tmp_path: Path) -> None:
    lines = ["t,u,z", *[f"{i * 0.01},1,{i}" for i in range(4)]]
    refuse(
        csv(tmp_path, lines),
        "columns: t, u, z",
        "missing output column: y",
        outputs=["y"],
        inputs=["u"],
    )


def test_mapping_to_undeclared_target_lists_declared_names(tmp_path: Path) -> None:
    lines = ["t,u,y", *[f"{i * 0.01},1,{i}" for i in range(4)]]
    msg = refuse(
        csv(tmp_path, lines), "unknown target 'x'", outputs=["y"], inputs=["u"], columns={"y": "x"}
    )
    assert "map to one of y, u, time, motor, record, ignore" in msg
    assert "setpoint_" not in msg  # explicit inputs: no set-point auto-detection


@pytest.mark.parametrize(
    ("kwargs", "expected"),
    [
        ({"outputs": ["time"]}, "'time' cannot name an output channel"),
        ({"outputs": ["y"], "inputs": ["record"]}, "'record' cannot name an input channel"),
        ({"outputs": ["y", "Y"]}, "'Y' is named twice"),
        ({"outputs": []}, "no output channels declared"),
        ({"outputs": "y"}, "outputs must be a list of names"),
        ({"outputs": ["y"], "inputs": ["Y"]}, "'y' is declared both as an output and as an input"),
        ({"outputs": ["y"], "units": {"z": "m"}}, "units names 'z', which is neither"),
        ({"units": {"motor": "rad/s"}}, "the motor speed must be in rpm"),
    ],
)
def test_contradictory_declarations(tmp_path: Path, kwargs: dict, expected: str) -> None:
    path = csv(tmp_path, [HEADER, *rows()])
    with pytest.raises(ConfigError) as info:
        read_measurements(path, **kwargs)
    assert expected in info.value.message and "fix:" in info.value.message


# ------------------------------------------------------------------------------ records


def test_error_in_second_file_names_that_file(tmp_path: Path) -> None:
    good = csv(tmp_path, [HEADER, *rows()], "good.csv")
    bad = csv(tmp_path, [HEADER, *rows(3), "0.03,1815,1500,x,355"], "bad.csv")
    with pytest.raises(DataError) as info:
        read_measurements([good, bad])
    assert info.value.message.startswith(f"{bad}: row 4 (line 5), column 'third'")
    assert str(good) not in info.value.message


def test_files_with_different_rates(tmp_path: Path) -> None:
    a = csv(tmp_path, [HEADER, *rows()], "a.csv")
    b = csv(tmp_path, [HEADER, *rows(step=0.02)], "b.csv")
    msg = refuse(b, "sample rate 50 Hz of", "differs from 100 Hz of", paths=[a, b])
    assert f"50 Hz of {b}" in msg and f"100 Hz of {a}" in msg


def test_files_with_different_inputs(tmp_path: Path) -> None:
    a = csv(tmp_path, [HEADER + ",supply_hz", *[f"{r},50" for r in rows()]], "a.csv")
    b = csv(tmp_path, [HEADER, *rows()], "b.csv")
    refuse(b, f"inputs none here but supply_hz in {a}", paths=[a, b])


def test_files_with_different_motor_or_units(tmp_path: Path) -> None:
    a = csv(tmp_path, [HEADER + ",motor", *[f"{r},1450" for r in rows()]], "a.csv")
    b = csv(tmp_path, [HEADER, *rows()], "b.csv")
    refuse(b, f"a motor column in {a} but not in {b}", paths=[a, b])
    c = csv(tmp_path, ["t,y [m]", *[f"{i * 0.01},{i}" for i in range(4)]], "c.csv")
    d = csv(tmp_path, ["t,y [mm]", *[f"{i * 0.01},{i}" for i in range(4)]], "d.csv")
    refuse(d, f"'y' is in mm here but in m in {c}", paths=[c, d], outputs=["y"])


def test_record_column_must_hold_whole_numbers(tmp_path: Path) -> None:
    lines = [
        "record,time,front,second,third,back",
        *[f"{k},{r}" for k, r in zip(["0", "0", "0.5", "1", "1", "1"], rows(), strict=True)],
    ]
    refuse(csv(tmp_path, lines), "row 3 (line 4), column 'record'", "'0.5' is not a whole number")
    lines[3] = lines[3].replace("0.5", "", 1)
    refuse(csv(tmp_path, lines), "row 3 (line 4), column 'record'", "is not a whole number")


def test_one_row_record(tmp_path: Path) -> None:
    lines = [
        "record,time,front,second,third,back",
        *[f"{k},{r}" for k, r in zip([0, 0, 1, 2, 2, 2], rows(), strict=True)],
    ]
    refuse(csv(tmp_path, lines), "row 3 (line 4), column 'record'", "record 1 has only one row")


def test_record_time_errors_name_file_rows(tmp_path: Path) -> None:
    times = [0.0, 0.01, 0.02, 5.0, 5.01, 5.005]  # second record goes back in its third row
    lines = [
        "record,time,front,second,third,back",
        *[f"{k},{t},1815,1500,450,355" for k, t in zip([0, 0, 0, 1, 1, 1], times, strict=True)],
    ]
    refuse(csv(tmp_path, lines), "row 6 (line 7)", "time goes backwards", "from row 5 (line 6)")


def test_records_with_different_rates(tmp_path: Path) -> None:
    times = [0.0, 0.01, 0.02, 0.0, 0.02, 0.04]
    lines = [
        "record,time,front,second,third,back",
        *[f"{k},{t},1815,1500,450,355" for k, t in zip([0, 0, 0, 1, 1, 1], times, strict=True)],
    ]
    refuse(
        csv(tmp_path, lines),
        "sample rate 50 Hz of record 1 (from row 4 (line 5))",
        "differs from 100 Hz of record 0",
    )


# -------------------------------------------------------------------------------- the split


def test_split_refuses_bad_fraction() -> None:
    series = MeasurementSeries(time_s=np.arange(10.0), values=np.ones((10, 4)))
    for fraction in (0.0, 1.0, 1.5):
        with pytest.raises(DataError, match="train_fraction"):
            chronological_split(series, fraction)
    with pytest.raises(DataError, match="too few"):
        chronological_split(series.slice(0, 3), 0.7)


# ---------------------------------------------------------------------------------- the CLI


def _cli() -> Callable[[list[str]], tuple[int, str]]:
    from typer.testing import CliRunner

    import drafttwin.cli.data_cmds  # noqa: F401  (registers `inspect`)
    from drafttwin.cli.typer_app import app

    runner = CliRunner()
    single = len(app.registered_commands) == 1  # typer collapses a one-command app

    def invoke(args: list[str]) -> tuple[int, str]:
        result = runner.invoke(app, args[1:] if single else args)
        assert result.exception is None or isinstance(result.exception, SystemExit)
        return result.exit_code, result.output

    return invoke


@pytest.mark.parametrize(
    ("lines", "expected"),
    [
        ([HEADER, *rows(3), "0.03,1815,x,450,355"], "row 4 (line 5), column 'second'"),
        (["when,front,second,third,back", *rows()], "no time column"),
        ([], "file is empty"),
    ],
)
def test_cli_inspect_refuses_with_exit_2(tmp_path: Path, lines: list[str], expected: str) -> None:
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(lines) + ("\n" if lines else ""))
    code, output = _cli()(["inspect", str(path)])
    output = " ".join(output.split())  # undo any line wrapping
    assert code == 2
    assert "Traceback" not in output
    assert expected in output and "bad.csv" in output
    assert [p.name for p in tmp_path.iterdir()] == ["bad.csv"]


def test_cli_inspect_refuses_bad_mapping_syntax(tmp_path: Path) -> None:
    path = csv(tmp_path, [HEADER, *rows()])
    code, output = _cli()(["inspect", str(path), "--columns", "v1front"])
    assert code == 2 and "--columns" in output and "Traceback" not in output


def test_cli_inspect_summary(tmp_path: Path) -> None:
    import json

    lines = [
        HEADER,
        *rows(4),
        "0.04,1815,1500,,355",
        "0.05,1815,1500,,355",
        "0.06,1815,1800,450,355",
    ]
    lines += [f"{0.07 + 0.01 * i:.2f},1815,1500,450,355" for i in range(3)]
    path = csv(tmp_path, lines)
    code, output = _cli()(["inspect", str(path), "--json"])
    assert code == 0, output
    summary = json.loads(output)
    assert summary["rows"] == 10
    assert summary["sample_rate_hz"] == pytest.approx(100.0)
    assert summary["channels"]["third"]["missing"] == 2
    assert summary["channels"]["third"]["longest_gap"] == 2
    assert summary["channels"]["second"]["outliers"] == 1
    assert summary["channels"]["front"]["mean"] == pytest.approx(1815.0)
    assert summary["channels"]["front"]["unit"] == "rpm" and summary["records"] == 1
    code, text = _cli()(["inspect", str(path), "--columns", "third=third"])
    assert code == 0 and "front" in text and "outliers" in text


def test_console_script_exits_2_without_traceback(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from drafttwin.cli import main

    path = csv(tmp_path, [HEADER, "0,1815,1500,450,355", "0,1815,1500,450,355"])
    monkeypatch.setattr("sys.argv", ["drafttwin", "inspect", str(path)])
    with pytest.raises(SystemExit) as info:
        main()
    assert info.value.code == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "Traceback" not in err
    assert str(path) in err and "row 2 (line 3)" in err and "duplicate time stamp" in err


def test_a_time_column_that_is_not_in_the_file_names_time_column(tmp_path: Path) -> None:
    refuse(csv(tmp_path, [HEADER, *rows()]), "--time-column", "'zz' is not in the file",
           time_column="zz")  # fmt: skip


def test_a_column_mapped_to_the_wrong_roller_is_refused_at_any_set_point():
    """The rollers turn in fixed ratios: a front column running as the second roller would
    is refused (diagnose had accepted a front/second swap and blamed the machine), while
    every column at one speed factor passes, be it 24 % of nominal or 125 %."""
    from drafttwin.data.units import check_units
    from drafttwin.errors import DataError

    nominal = {"front": 1815.7, "second": 434.7, "third": 426.1, "back": 355.1, "motor": 1450.0}
    names = list(nominal)
    rng = np.random.default_rng(0)
    for factor in (0.24, 1.0, 1.25):
        rpm = np.array([nominal[n] * factor for n in names]) * (
            1 + 1e-4 * rng.standard_normal((500, 5))
        )
        check_units(rpm, names, "r.csv", nominal_rpm=nominal)  # consistent: accepted
        swapped = rpm[:, [1, 0, 2, 3, 4]]  # the front and second columns exchanged
        with pytest.raises(DataError, match="runs as 'second' would") as err:
            check_units(swapped, names, "r.csv", nominal_rpm=nominal)
        assert "--columns front=second,second=front" in str(err.value)


def test_the_suggested_column_map_can_be_pasted_into_a_shell(tmp_path):
    """Names with spaces were suggested unquoted: pasted, the shell split them."""
    import shlex

    path = tmp_path / "spaced.csv"
    path.write_text("time,front roller [rpm],second roller [rpm],third roller [rpm],back roller [rpm]\n"
                    + "".join(f"{0.01 * i:.2f},1815,1500,450,355\n" for i in range(6)))  # fmt: skip
    with pytest.raises(DataError) as info:
        read_measurements(path)
    fix = info.value.message.split("map yours: ", 1)[1]
    args = shlex.split(fix)
    assert args[0] == "--columns" and len(args) == 2
    mapping = dict(pair.split("=") for pair in args[1].split(","))
    assert len(read_measurements(path, columns=mapping)) == 6


def test_inspect_says_what_fit_says_of_a_clock_that_steps_whole_seconds(tmp_path):
    """A millisecond clock under a name without a unit read 0.1 Hz in inspect without a
    word, while fit noted it."""
    import json

    from typer.testing import CliRunner

    from drafttwin.cli import app

    path = tmp_path / "slow.csv"
    path.write_text("zeit,front,second,third,back\n"
                    + "".join(f"{10 * i},1815,1500,450,355\n" for i in range(20)))  # fmt: skip
    args = ["inspect", str(path), "--time-column", "zeit"]
    said = " ".join(CliRunner().invoke(app, args).output.split())
    assert (
        "note: the records step by 10 s (0.1 Hz): if the time column counts milliseconds, "
        "name it 'time [ms]'"
    ) in said
    out = json.loads(CliRunner().invoke(app, [*args, "--json"]).stdout)
    assert out["notes"][0].startswith("the records step by 10 s")
