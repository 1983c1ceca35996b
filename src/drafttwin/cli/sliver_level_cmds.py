"""``drafttwin sliver level``: the autoleveller's action point and intensity from running data."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any

from rich.table import Table

from drafttwin.cli._groups import stops_cleanly, with_group
from drafttwin.cli._options import JsonOpt, file_in, machine_name, number
from drafttwin.cli.sliver_cmds import FibreOptions, sliver_app
from drafttwin.cli.typer_app import console, print_json
from drafttwin.errors import ConfigError, DataError

LevelRecordOpt = Annotated[Path, file_in("--data", "A levelling drawframe's record: a plant "
                           "record made with generate --sliver (or its .sliver file), or any "
                           "file with delivered_length_m, time, linear_density_ktex (delivery "
                           "sensor), infeed_ktex (infeed scanning rollers) and fed_length_m "
                           "(the store's length clock).")]  # fmt: skip
ActionPointOpt = Annotated[float | None, number("--action-point", "The leveller's current action point setting, mm of fed sliver from the scanning rollers (default: the record's sidecar).")]  # fmt: skip
IntensityOpt = Annotated[float | None, number("--intensity", "The leveller's current intensity (default: the record's sidecar; 0: no leveller).")]  # fmt: skip
ReferenceOpt = Annotated[float | None, number("--reference-ktex", "The fed count the leveller levels to, all slivers together, ktex (default: the sidecar's feed, else the infeed readings' median; refused beyond 0.5-2 x that median).")]  # fmt: skip
MaxLengthOpt = Annotated[float | None, number("--max-length", "Analyse at most this many metres of delivered sliver from the record's start.")]  # fmt: skip
SearchOpt = Annotated[float, number("--search", "Action points searched either side of the current setting, mm.")]  # fmt: skip
LevelMachineOpt = Annotated[str | None, machine_name("--machine", "In a log of several machines (plant serve --machines N --sliver --log): the machine whose rows are read.")]  # fmt: skip


@sliver_app.command("level")
@with_group("fibre_options", FibreOptions)
@stops_cleanly("nothing was written")
def level_cmd(
    *,  # keyword-only: the option group below has no default
    data: LevelRecordOpt,
    action_point: ActionPointOpt = None,
    intensity: IntensityOpt = None,
    reference_ktex: ReferenceOpt = None,
    max_length: MaxLengthOpt = None,
    search: SearchOpt = 120.0,
    machine: LevelMachineOpt = None,
    fibre_options: FibreOptions,
    as_json: JsonOpt = False,
) -> None:
    """Find the autoleveller's action point and intensity from running data (infeed and
    delivery readings of a few hundred metres) and recommend them, with the CV, CV(1 m),
    CV(3 m) and CV(5 m) they are expected to give beside the current setting's, a 95 %
    interval and the metres the estimate needed. Nothing is written to the machine."""
    from dataclasses import replace

    from drafttwin.sliver.action_point import find_action_point
    from drafttwin.sliver.leveller_record import LevellerSetting, read_leveller_record
    from drafttwin.sliver.staple import resolve_fibres

    got = read_leveller_record(data, machine=machine)
    setting = got.setting
    if setting is None:
        if action_point is None:
            raise ConfigError("the record names no action point setting", source=data,
                              where="--action-point",
                              fix="give the current setting with --action-point MM (without a "
                              "leveller: the machine's nominal one, the centre of the search) "
                              "and --intensity I (0 without a leveller)")  # fmt: skip
        setting = LevellerSetting(action_point, 1.0 if got.had_leveller else 0.0)
    setting = replace(setting,
                      action_point_mm=setting.action_point_mm if action_point is None
                      else action_point,
                      intensity=setting.intensity if intensity is None else intensity,
                      reference_ktex=setting.reference_ktex if reference_ktex is None
                      else reference_ktex)  # fmt: skip
    if reference_ktex is not None:
        _check_reference(reference_ktex, got.record.infeed_ktex)
    fibres = resolve_fibres(fibre_options.given(), got.staple)
    record = got.record if max_length is None else got.record.head(max_length)
    try:
        advice = find_action_point(record, setting, fibres.staple, got.delivery,
                                   search_mm=search)  # fmt: skip
    except DataError as exc:
        if max_length is None or record.length_m >= got.record.length_m:
            raise
        raise DataError(exc.problem, source=data, where="--max-length",
                        fix=f"give a larger --max-length (the record holds "
                        f"{got.record.length_m:.0f} m)") from None  # fmt: skip
    if as_json:
        print_json({**advice.to_dict(), "fibres": fibres.to_dict(advice.current.count_ktex)})
        return
    _print(advice, data)
    if fibres.source == "assumed":
        console.print(fibres.note())


def _cv(value: float) -> str:
    """A CV in the table; a length the record is too short for: -."""
    return f"{value:.3f}" if math.isfinite(value) else "-"


def _check_reference(reference_ktex: float, infeed_ktex: Any) -> None:
    """Refuse a reference count far from what the infeed sensor reads (the fed count of all
    slivers together: one sliver's count is a common slip)."""
    import numpy as np

    median = float(np.nanmedian(infeed_ktex))
    if not 0.5 * median <= reference_ktex <= 2.0 * median:
        raise ConfigError(f"{reference_ktex:g} ktex, but the infeed sensor reads a median of "
                          f"{median:.4g} ktex (the fed count of all slivers together)",
                          where="--reference-ktex",
                          fix=f"give the fed count, about {median:.4g} ktex, or leave "
                          "--reference-ktex out")  # fmt: skip


def _print(advice: Any, data: Path) -> None:
    a = advice
    lo, hi = a.action_point_interval_mm
    table = Table(title=f"{data.name}: {a.metres_used:.0f} m of sliver")
    table.add_column("", no_wrap=True)
    for col in ("action point mm", "intensity", "CV %", "CV 1 m %", "CV 3 m %", "CV 5 m %"):
        table.add_column(col, justify="right")
    rows = [("current", a.current_action_point_mm, a.current_intensity, a.current)]
    if a.identifiable:  # a setting the record does not place is not recommended
        rows.append(("recommended", a.recommended_action_point_mm, a.recommended_intensity,
                     a.recommended))  # fmt: skip
    for name, point, inten, ev in rows:
        table.add_row(
            name,
            "none" if point is None else f"{point:.1f}",
            f"{inten:.2f}",
            *(_cv(v) for v in (ev.cv_pct, ev.cv_1m_pct, ev.cv_3m_pct, ev.cv_5m_pct)),
        )
    console.print(table)
    if a.identifiable:
        needed = "more than the record" if a.metres_needed is None else f"{a.metres_needed:.0f} m"
        console.print(f"action point {a.recommended_action_point_mm:.1f} mm (95 % {lo:.1f}-"
                      f"{hi:.1f}), intensity {a.recommended_intensity:.2f} (95 % "
                      f"{a.intensity_interval[0]:.2f}-{a.intensity_interval[1]:.2f}); within +-5 "
                      f"mm from {needed} of sliver; the material reaches the delivery at "
                      f"{a.estimated_action_point_mm:.1f} mm, the drive follows with "
                      f"{_drive(a.drive_time_constant_s, a.drive_time_constant_interval_s)}; "
                      "CVs as the delivery sensor reads them; the twin writes no setting")  # fmt: skip
    if any(not math.isfinite(v) for v in (a.current.cv_5m_pct, a.current.cv_3m_pct)):
        console.print("CV 3 m / 5 m: - where the record is too short for that length")
    if not a.identifiable:
        edge = any("searched range" in note for note in a.notes)
        why = ("its feed varies too little (the interval is wider than 50 mm)" if hi - lo > 50
               else "--search widens the searched range" if edge else "why, below")  # fmt: skip
        console.print(f"the record does not say where the action point is, so nothing is "
                      f"recommended: {why}")  # fmt: skip
    for note in a.notes:
        console.print(note)


def _drive(tau_s: float, interval_s: tuple[float, float]) -> str:
    """The drive's time constant as the advice took it, with the record's 95 % interval."""
    lo, hi = (1000 * t for t in interval_s)
    return f"{1000 * tau_s:.1f} ms (95 % {lo:.0f}-{hi:.0f} ms)"
