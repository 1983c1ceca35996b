"""``drafttwin sliver spectrogram | wavelengths | diagnose``: reading a sliver."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from drafttwin.cli._common import check_output_suffix
from drafttwin.cli._groups import stops_cleanly, with_group
from drafttwin.cli._options import JsonOpt, TrainOptions, file_in, file_out, number
from drafttwin.cli.sliver_cmds import (
    FibreOptions,
    FibreScaleReadOpt,
    GaugesOpt,
    causes_table,
    evenness_table,
    sliver_app,
    zones_from,
)
from drafttwin.cli.typer_app import console, print_json
from drafttwin.errors import ConfigError

SliverRecordOpt = Annotated[Path, file_in("--data", "Sliver record: a length column "
                           "(delivered_length_m, length_m, ... or --length-column) and a density "
                           "column (linear_density_ktex or --column): drafttwin sliver simulate, "
                           "generate --sliver (its speed record or its .sliver file), a tester's "
                           "export.")]  # fmt: skip
ColumnOpt = Annotated[str | None, typer.Option("--column", help="Density column (default: "
                      "linear_density_ktex, else the one numeric column beside the length).")]  # fmt: skip
LengthColumnOpt = Annotated[str | None, typer.Option("--length-column", help="Delivered-length "
                            "column (default: delivered_length_m, length_m, position_m, ... with "
                            "_m, _cm or _mm); its unit from its name or --length-unit.")]  # fmt: skip
LengthUnitOpt = Annotated[str | None, typer.Option("--length-unit", help="Unit of the length "
                          "column when its name does not say it: m, cm or mm.")]  # fmt: skip
SensorOpt = Annotated[float, number("--sensor-mm", "Averaging length of the sensor that read the record, mm (for the ideal curve).")]  # fmt: skip
ChannelTableOpt = Annotated[Path | None, file_out("--out", "The channel table (.csv or .parquet).")]  # fmt: skip


def read_record(data: Path, column: str | None, length_column: str | None,
                length_unit: str | None, fibre_options: FibreOptions,
                option: str = "--data") -> tuple[Any, Any, Any]:  # fmt: skip
    """A sliver record (or the sliver channel beside a plant record), the fibres to read it
    with (options, else the record's sidecar, else assumed) and what lies beside it."""
    from dataclasses import replace

    from drafttwin.sliver import read_sliver
    from drafttwin.sliver.record import sliver_beside
    from drafttwin.sliver.staple import resolve_fibres

    beside = sliver_beside(data)
    fibres = resolve_fibres(fibre_options.given(), beside.staple if beside else None)
    record = read_sliver(beside.sliver if beside else data, column, option=option,
                         length_column=length_column, length_unit=length_unit)  # fmt: skip
    return replace(record, staple=fibres.staple), fibres, beside


@sliver_app.command("spectrogram")
@with_group("fibre_options", FibreOptions)
@stops_cleanly("nothing was written")
def spectrogram_cmd(
    *,  # keyword-only: the option group below has no default
    data: SliverRecordOpt,
    column: ColumnOpt = None,
    length_column: LengthColumnOpt = None,
    length_unit: LengthUnitOpt = None,
    fibre_options: FibreOptions,
    sensor_mm: SensorOpt = 0.0,
    fibre_scale: FibreScaleReadOpt = None,
    out: ChannelTableOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Count, CV %, U %, CV at cut lengths and the spectrogram as evenness testers draw it
    (10 channels per octave, ideal curve of a random sliver of the same fibres, significant
    channels, chimneys)."""
    from drafttwin.cli._common import write_frame
    from drafttwin.sliver.irregularity import (
        evenness,
        ideal_variance_length_cv_pct,
        variance_length_curve,
    )
    from drafttwin.sliver.spectra import spectrogram

    if out is not None:
        check_output_suffix(out)
    sl, fibres, beside = read_record(data, column, length_column, length_unit, fibre_options)
    fibre_scale = _fibre_scale(fibre_scale, beside)
    staple = fibres.staple
    ev = evenness(sl.linear_density_ktex, sl.step_m, staple, fibre_scale)
    spec = spectrogram(sl.linear_density_ktex, sl.step_m, staple, fibre_scale=fibre_scale,
                       sensor_length_m=sensor_mm * 1e-3)  # fmt: skip
    frame = spec.to_frame()
    if out is not None:
        write_frame(frame, out)
    if as_json:
        lengths, cv = variance_length_curve(sl.linear_density_ktex, sl.step_m)
        ideal_cv = ideal_variance_length_cv_pct(staple, sl.count_ktex, lengths, fibre_scale)
        print_json({"evenness": ev.to_dict(), "fibres": fibres.to_dict(sl.count_ktex),
                    "spectrogram": frame.to_dict(orient="list"),
                    "variance_length": {"length_m": lengths.tolist(), "cv_pct": cv.tolist(),
                                        "ideal_cv_pct": ideal_cv.tolist()}})  # fmt: skip
        return
    console.print(evenness_table(ev, f"{data.name}: {sl.length_m:.1f} m"))
    console.print(fibres.note())
    table = Table(title="spectrogram (significant channels; * chimney)")
    for col in ("wavelength", "amplitude %", "ideal %", "base %", ""):
        table.add_column(col, justify="right")
    for _, r in frame[frame["significant"]].iterrows():
        ideal = "" if r["ideal_pct"] != r["ideal_pct"] else f"{r['ideal_pct']:.3f}"
        table.add_row(f"{r['wavelength_m'] * 100:.2f} cm", f"{r['amplitude_pct']:.3f}", ideal,
                      f"{r['base_pct']:.3f}", "*" if r["chimney"] else "")  # fmt: skip
    console.print(table)
    if out is not None:
        console.print(f"wrote {out}")


MotorRpmOpt = Annotated[float | None, number("--motor-rpm", "Motor speed, rpm (default: the running point by torque balance).")]  # fmt: skip
HarmonicsOpt = Annotated[int, number("--harmonics", "Harmonics listed per element.")]
TableOutOpt = Annotated[Path | None, file_out("--out", "The table (.csv or .parquet).")]


@sliver_app.command("wavelengths")
@with_group("drive", TrainOptions)
def wavelengths_cmd(
    drive: TrainOptions,
    motor_rpm: MotorRpmOpt = None,
    harmonics: HarmonicsOpt = 3,
    out: TableOutOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Every rotating element of the drive train (motor, shafts, pulleys, belt pass,
    sprockets, chain pass and teeth, each gear and mesh, each roller) with its frequency and
    its wavelength on the delivered sliver, and the rollers it moves."""
    from drafttwin.cli._common import write_frame
    from drafttwin.sliver import wavelength_table

    if out is not None:
        check_output_suffix(out)
    table = wavelength_table(drive.load(), motor_rpm=motor_rpm, harmonics=harmonics)
    if out is not None:
        write_frame(table.to_frame(), out)
    if as_json:
        print_json(table.to_dict())
        return
    shown = Table(title=f"{table.train}: delivery {table.delivery_m_min:.2f} m/min, motor "
                  f"{table.motor_rpm:.1f} rpm")  # fmt: skip
    for col in ("element", "kind", "Hz", "wavelength", "harmonics", "moves"):
        shown.add_column(col, justify="right" if col in ("Hz", "wavelength") else "left",
                         overflow="fold")  # fmt: skip
    for e in table.elements:
        harm = ", ".join(_cm(w) for w in e.harmonics_m(harmonics)[1:])
        shown.add_row(e.name, e.kind, f"{e.frequency_hz:.3f}", _cm(e.wavelength_m), harm,
                      ",".join(e.rollers))  # fmt: skip
    console.print(shown)
    if out is not None:
        console.print(f"wrote {out}")


def _cm(x: float) -> str:
    return f"{x * 100:.2f} cm" if x < 1 else f"{x:.3f} m"


SliverOrSpeedsOpt = Annotated[Path | None, file_in("--data", "A sliver record, or a speed record "
                             "with a sliver channel beside it (generate --sliver): its speeds "
                             "then count as --speeds.")]  # fmt: skip
TesterOpt = Annotated[Path | None, file_in(
    "--spectrogram", "An evenness tester's spectrogram table instead: wavelength_m | "
    "wavelength_cm | wavelength_mm and amplitude_pct (optional significant).")]  # fmt: skip
EncodersOpt = Annotated[Path | None, file_in("--speeds", "The roller speeds recorded with the "
                        "sliver (same clock): the encoders' word on each look-alike.")]  # fmt: skip
HealthySliverOpt = Annotated[Path | None, file_in(
    "--reference", "A healthy sliver record of the same machine (or a speed record with one "
    "beside it): chimneys no higher than 1.5 x its channel are the machine's own lines, named "
    "but not counted as new.")]  # fmt: skip
SensorOrSidecarOpt = Annotated[float | None, number("--sensor-mm", "Averaging length of the "
                              "sensor that read --data, mm (default: the plant's sidecar, else "
                              "0).")]  # fmt: skip
MatchedOpt = Annotated[int, number("--harmonics", "Harmonics matched per element.")]
TestedOpt = Annotated[float | None, number("--tested-m", "With --spectrogram: the sliver "
                      "length the tester read, m (its report states it): a channel with fewer "
                      "than 25 periods in it is then not significant. Without it (and without "
                      "a 'significant' column) every channel counts.")]  # fmt: skip
PageOpt = Annotated[Path | None, file_out("--report", "An HTML page for the quality engineer.")]
NominalOpt = Annotated[float | None, number("--nominal-count", "The machine's nominal delivered "
                       "count, ktex: the mean over each 5 m is held to +-5 % of it (default: the "
                       "record's sidecar, feed count x doublings / total draft; else not "
                       "checked).")]  # fmt: skip


@sliver_app.command("diagnose")
@with_group("drive", TrainOptions)
@with_group("fibre_options", FibreOptions)
@stops_cleanly("nothing was written")
def diagnose_cmd(
    *,  # keyword-only: the option groups below have no default
    data: SliverOrSpeedsOpt = None,
    spectrogram_file: TesterOpt = None,
    speeds: EncodersOpt = None,
    reference: HealthySliverOpt = None,
    column: ColumnOpt = None,
    length_column: LengthColumnOpt = None,
    length_unit: LengthUnitOpt = None,
    drive: TrainOptions,
    fibre_options: FibreOptions,
    gauges: GaugesOpt = "44,40,46",
    sensor_mm: SensorOrSidecarOpt = None,
    harmonics: MatchedOpt = 8,
    fibre_scale: FibreScaleReadOpt = None,
    tested_m: TestedOpt = None,
    nominal_count: NominalOpt = None,
    report: PageOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Name the drive element behind each chimney of a sliver record or a tester's
    spectrogram: wavelength match with the machine's kinematics, harmonics, the drafting
    transfer (what speed modulation each element would need), look-alikes that share a
    wavelength, feed faults; with --speeds, the roller encoders' share of each chimney. A
    sliver record's count is held to +-5 % of the nominal over each 5 m (the sidecar's, or
    --nominal-count), as a quality monitor holds it."""
    from dataclasses import replace

    from drafttwin.sliver.count import nominal_count_ktex, watch_count
    from drafttwin.sliver.diagnose import diagnose_sliver
    from drafttwin.sliver.spectra import read_tester_spectrogram
    from drafttwin.sliver.staple import resolve_fibres

    if (data is None) == (spectrogram_file is None):
        raise ConfigError("give one of --data and --spectrogram", where="--data",
                          fix="a sliver record (--data) or a tester's table (--spectrogram)")  # fmt: skip
    if report is not None and report.suffix.lower() not in (".html", ".htm"):
        raise ConfigError(f"'{report.name}' is not an .html file", where="--report",
                          fix="name the page *.html")  # fmt: skip
    if speeds is not None and spectrogram_file is not None:
        raise ConfigError("--speeds places a chimney by the encoders along a sliver record, "
                          "which a tester's spectrogram table is not", where="--speeds",
                          fix="give the sliver record (--data) with --speeds, or leave --speeds "
                          "out")  # fmt: skip
    if nominal_count is not None and data is None:
        raise ConfigError("--nominal-count holds a sliver record's count to its limit; a "
                          "tester's spectrogram table has no count", where="--nominal-count",
                          fix="give it with --data, or leave it out")  # fmt: skip
    if tested_m is not None and spectrogram_file is None:
        raise ConfigError("--tested-m is the length an evenness tester read; a sliver record "
                          "(--data) has its own", where="--tested-m",
                          fix="give it with --spectrogram, or leave it out")  # fmt: skip
    zones = zones_from(gauges)
    train = drive.load()
    record: Any
    notes: list[str] = []
    if data is not None:
        record, fib, beside = read_record(data, column, length_column, length_unit,
                                          fibre_options)  # fmt: skip
        if beside is not None:
            speeds = speeds if speeds is not None else beside.speeds
            sensor_mm = beside.sensor_mm if sensor_mm is None else sensor_mm
        record = replace(record, fibre_scale=_fibre_scale(fibre_scale, beside))
        if nominal_count is None and beside is not None:
            nominal_count = nominal_count_ktex(beside.sidecar)
    else:
        assert spectrogram_file is not None
        fib = resolve_fibres(fibre_options.given())
        record = read_tester_spectrogram(spectrogram_file, staple=fib.staple,
                                         tested_length_m=tested_m)  # fmt: skip
        if tested_m is None and bool(record.significant.all()):
            notes.append("the tested length is unknown and the table marks no channel as not "
                         "significant: every channel counts, the longest waves too (fewer "
                         "than 25 periods read are not significant); give --tested-m, the "
                         "metres the tester read")  # fmt: skip
    fibres = fib.staple
    ref = None
    if reference is not None:
        ref, _, ref_beside = read_record(reference, column, length_column, length_unit,
                                         fibre_options, option="--reference")  # fmt: skip
        ref = replace(ref, staple=fibres, fibre_scale=_fibre_scale(fibre_scale, ref_beside))
    dx = diagnose_sliver(record, train, fibres, zones, harmonics=harmonics,
                         sensor_length_m=(sensor_mm or 0.0) * 1e-3, reference=ref)  # fmt: skip
    if speeds is not None and data is not None:
        dx = _with_speeds(dx, record, speeds, fibres, zones)
    count = None if nominal_count is None else watch_count(
        record.delivered_length_m, record.linear_density_ktex, record.time_s, nominal_count)  # fmt: skip
    if report is not None:
        from drafttwin._io import atomic_path
        from drafttwin.report.sliver import sliver_page

        with atomic_path(report) as tmp:
            tmp.write_text(sliver_page(dx, title="What the sliver says",
                                       source=str(data or spectrogram_file)), encoding="utf-8")  # fmt: skip
    if as_json:
        mean = dx.evenness.count_ktex if dx.evenness is not None else None
        limit = {} if data is None else {
            "count_limit": None if count is None else count.status(),
            "count_excursions": [] if count is None else [e.to_dict() for e in count.excursions]}  # fmt: skip
        print_json({**dx.to_dict(), "fibres": fib.to_dict(mean), **limit,
                    **({"notes": notes} if notes else {})})  # fmt: skip
        return
    for note in notes:
        console.print(f"[yellow]note:[/] {note}")
    if dx.evenness is not None:
        console.print(evenness_table(dx.evenness, f"{Path(str(data)).name}"))
    console.print(fib.note())
    if data is not None:
        _print_count(count)
    if not dx.causes:
        console.print("no significant chimney" + (" beyond the reference" if ref else ""))
    else:
        console.print(causes_table(dx.causes))
    for c in dx.known:
        console.print(f"the machine's own line (in --reference): {c.wavelength_m * 100:.2f} cm, "
                      f"{c.amplitude_pct:.3f} %: {c.verdict}")  # fmt: skip
    if report is not None:
        console.print(f"wrote {report}")


def _print_count(count: Any) -> None:
    """The count's limit: each excursion, or that it held, or why it was not checked."""
    if count is None:
        console.print("count limit not checked: the record names no nominal count "
                      "(--nominal-count KTEX)")  # fmt: skip
        return
    for e in count.excursions:
        console.print(("[red]" if e.out else "") + e.text() + ("[/]" if e.out else ""),
                      highlight=False)  # fmt: skip
    if not count.excursions:
        console.print(f"count within +-{count.limit_pct:g} % of the nominal "
                      f"{count.nominal_ktex:.3f} ktex over every {count.length_m:g} m")  # fmt: skip


def _with_speeds(dx: Any, record: Any, speeds: Path, fibres: Any, zones: Any) -> Any:
    from drafttwin.cli.sliver_cmds import read_speed_file
    from drafttwin.sliver.encoders import with_encoders

    series = read_speed_file(speeds)
    rpm = {r: series.values[:, series.channels.index(r)] for r in series.channels}
    return with_encoders(dx, record, series.time_s, rpm, fibres, zones)


def _fibre_scale(given: float | None, beside: Any) -> float:
    """``--fibre-scale``, else the record's sidecar's, else 1 (every fibre drawn): the
    lumping of a generated record had been lost, Martindale's limit halved for a scale of 4."""
    if given is not None:
        return given
    said = None if beside is None else beside.fibre_scale
    return 1.0 if said is None else said
