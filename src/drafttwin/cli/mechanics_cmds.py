"""``drafttwin kinematics`` and ``drafttwin simulate``: the mechanistic model."""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import numpy as np
import pandas as pd
import typer
from rich.table import Table

from drafttwin._constants import ROLLERS
from drafttwin._limits import check_rk4_steps, check_samples
from drafttwin.cli._common import check_output_suffix, write_frame
from drafttwin.cli._groups import stops_cleanly, with_group
from drafttwin.cli._options import (
    DurationOpt,
    JsonOpt,
    QuietOpt,
    TrainOptions,
    file_in,
    file_out,
    number,
)
from drafttwin.cli._stream import FrameStream, RunningStats, frame_stream
from drafttwin.cli.typer_app import app, console, err_console, print_json, progress_bar

if TYPE_CHECKING:
    from drafttwin.mechanics import (
        DriveTrain,
        Kinematics,
        OperatingPoint,
        SimulationPiece,
        SimulationStream,
    )

MotorRpmOpt = Annotated[float | None, number("--motor-rpm", "Motor speed, rpm (default: the "
                       "motor's rated speed).")]  # fmt: skip


@app.command()
@with_group("drive", TrainOptions)
def kinematics(
    drive: TrainOptions,
    motor_rpm: MotorRpmOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Nominal roller speeds, surface speeds, drafts, excitation and eigenfrequencies.

    Pure kinematics (rigid couplings, no slip, no creep): no simulation is run.
    """
    from drafttwin.mechanics import kinematics as compute
    from drafttwin.mechanics import operating_point

    train = drive.load()
    kin = compute(train, motor_rpm)
    if train.spec.motor is None:  # driven by external torques only: no running state
        if as_json:
            print_json(kin.to_dict())
            return
        if kin.rollers:  # it had printed JSON without --json
            _roller_table(train, kin, None)
        console.print("no [motor]: the train runs on its input torques, so there is no running "
                      "state (operating point) to show", markup=False)  # fmt: skip
        _frequencies(kin)
        return
    op = operating_point(train)
    if as_json:
        out = kin.to_dict()
        out["train"] = train.spec.train.name
        out["operating_point"] = {
            "motor_rpm": op.motor_rpm,
            "slip": op.slip,
            "motor_torque_nm": op.motor_torque_nm,
            "roller_rpm": op.roller_rpm,
            "belt_creep": op.belt_creep,
        }
        if train.spec.output or not kin.rollers:  # what the text's channel table shows
            out["operating_point"]["output_channels"] = _output_rows(train, op)
            out["input_channels"] = {c.channel: {"drives": c.drives, "node": c.node}
                                     for c in train.input_channels()}  # fmt: skip
        print_json(out)
        return
    if kin.rollers:
        _roller_table(train, kin, op)
    if train.spec.output or not kin.rollers:
        _output_table(train, op)
    motor = train.spec.motor
    # the motor's supply_hz is the set-point it runs at, which need not be the rated one
    rated = motor is not None and motor.supply_hz == motor.rated_supply_hz
    supply = "the rated supply" if rated or motor is None else f"a {motor.supply_hz:g}-Hz supply"
    console.print(
        f"* running: torque balance at {supply} with motor slip {op.slip * 100:.3f} % "
        f"({op.motor_rpm:.2f} rpm, {op.motor_torque_nm:.2f} N m)"
        + "".join(f", belt creep {k} {v * 100:.4f} %" for k, v in op.belt_creep.items())
    )
    if motor_rpm is not None:
        console.print(f"--motor-rpm {motor_rpm:g} sets the nominal columns; the running "
                      "column (*) stays the rated supply's (the JSON's operating_point too)")  # fmt: skip
    _frequencies(kin)


def _frequencies(kin: Kinematics) -> None:
    freqs = {**kin.mesh_frequencies_hz, **kin.chain_tooth_frequencies_hz}
    if freqs:
        console.print("mesh / chain-tooth frequencies (Hz): "
                      + ", ".join(f"{k} {v:.1f}" for k, v in freqs.items()))  # fmt: skip
    console.print("torsional eigenfrequencies (Hz):     "
                  + ", ".join(f"{f:.1f}" for f in kin.eigenfrequencies_hz))  # fmt: skip


def _roller_table(train: DriveTrain, kin: Kinematics, op: OperatingPoint | None) -> None:
    table = Table(title=f"{train.spec.train.name}: nominal kinematics at {kin.motor_rpm:g} rpm")
    cols = ("roller", "diameter mm", "rpm", "surface m/min", *(("running rpm*",) if op else ()))
    for col in cols:
        table.add_column(col, justify="right" if col != "roller" else "left")
    for name, r in kin.rollers.items():
        running = () if op is None else (f"{op.roller_rpm[name]:.2f}",)
        table.add_row(name, f"{r.diameter_mm:g}", f"{r.rpm:.2f}", f"{r.surface_speed_m_min:.3f}",
                      *running)  # fmt: skip
    console.print(table)
    console.print(f"delivery speed  {kin.delivery_speed_m_min:.2f} m/min")
    console.print("drafts          " + ", ".join(f"{k} {v:.4f}" for k, v in kin.drafts.items()))


def _output_rows(train: DriveTrain, op: OperatingPoint) -> dict[str, dict[str, Any]]:
    """Each measured output channel's node, unit and value at the running operating point."""
    from drafttwin.mechanics.steady_state import RPM

    rows = {}
    for m in train.output_channels():
        rpm = np.array([op.node_speed_rad_s[train.node_index(m.node)] * RPM])
        rows[m.channel] = {"node": m.node, "unit": m.unit, "running": float(m.from_rpm(rpm)[0])}
    return rows


def _output_table(train: DriveTrain, op: OperatingPoint) -> None:
    """The measured output channels at the running operating point, in their units."""
    table = Table(title=f"{train.spec.train.name}: output channels at the operating point*")
    for col in ("channel", "node", "unit", "running*"):
        table.add_column(col, justify="right" if col == "running*" else "left")
    for channel, row in _output_rows(train, op).items():
        table.add_row(channel, row["node"], row["unit"], f"{row['running']:.4g}")
    console.print(table)
    inputs = ", ".join(f"{c.channel} -> {c.drives}" + (f" on {c.node}" if c.node else "")
                       for c in train.input_channels())  # fmt: skip
    if inputs:
        console.print(f"input channels  {inputs}")


OutputRateOpt = Annotated[float | None, number("--rate", "Output rate, Hz (interval means; "
                         "default: the drive train's [solver] output_rate_hz).")]  # fmt: skip
StepOpt = Annotated[float | None, number("--dt", "Longest RK4 step, s, as the drive-train file's "
                   "[solver] dt_s (default: the file's): shortened so that whole steps fill each "
                   "output interval; the summary names the step used.")]  # fmt: skip
SettleOpt = Annotated[float | None, number("--settle", "Settling time before recording, s "
                      "(default from config).")]  # fmt: skip
SetpointsOpt = Annotated[Path | None, file_in(
    "--setpoints", "Follow the input columns of a recorded file (those the train's \\[\\[input]] "
    "tables map, e.g. supply_hz or u) on its time grid, record by record, and write the output "
    "channels: a simulator output file for --mechanistic. --duration and --rate then come from "
    "the file.")]  # fmt: skip
SetpointColumnsOpt = Annotated[str | None, typer.Option("--columns", help=(
    "With --setpoints: map the file's columns to the train's input channels (and time), "
    "FILE_COLUMN=CHANNEL[,...], e.g. volts=u or zeit=time."))]  # fmt: skip
ChannelsOutOpt = Annotated[Path | None, file_out("--out", "Write time + the output channels to .csv or .parquet.")]  # fmt: skip
ReducedOpt = Annotated[bool, typer.Option("--reduced", help=(
    "Simulate the reduced drive train: couplings whose modes lie above --cutoff-hz made rigid "
    "and their inertias merged (belts stay compliant, with creep), at a much larger step "
    "(default: from the highest remaining mode). 65x faster on the FA320A; its 0.1 s block "
    "means agree with the full model to 2e-5 (docs/mechanics.md)."))]  # fmt: skip
CutoffOpt = Annotated[float | None, number("--cutoff-hz", "Cut-off of --reduced, Hz (default 200; implies --reduced).")]  # fmt: skip


@app.command()
@with_group("drive", TrainOptions)
@stops_cleanly("nothing was written")
def simulate(
    drive: TrainOptions, duration: DurationOpt = 10.0, rate: OutputRateOpt = None,
    dt: StepOpt = None, settle: SettleOpt = None, setpoints: SetpointsOpt = None,
    columns: SetpointColumnsOpt = None, out: ChannelsOutOpt = None, reduced: ReducedOpt = False,
    cutoff_hz: CutoffOpt = None, quiet: QuietOpt = False,
) -> None:  # fmt: skip
    """Simulate the drive train (numba RK4) and summarise its output channels (the rollers
    and the motor for the FA320A).

    Values are means over each output interval, as an encoder reports them.
    """
    from drafttwin.cli._data import pairs
    from drafttwin.errors import ConfigError

    if columns is not None and setpoints is None:
        raise ConfigError("maps the columns of a --setpoints file, and none is given", where="--columns",
                          fix="add --setpoints FILE, or leave --columns out")  # fmt: skip
    mapping = pairs(columns, "--columns", "volts=u") or None
    train = drive.load()
    if setpoints is None:  # refuse a run that would never end before anything starts
        out_rate = train.spec.solver.output_rate_hz if rate is None else rate
        check_samples(duration, out_rate, where="--duration, --rate")
    if dt is not None:
        check_rk4_steps(duration, dt, settle_s=settle or 0.0, where="--dt")
    if reduced or cutoff_hz is not None:
        from drafttwin.mechanics import DEFAULT_CUTOFF_HZ, reduce

        train = reduce(train, DEFAULT_CUTOFF_HZ if cutoff_hz is None else cutoff_hz)
        assert train.reduction is not None
        console.print(train.reduction.summary())
    if out is not None:
        check_output_suffix(out)
    stats = RunningStats()
    if setpoints is not None:
        frame = _follow(train, setpoints, dt, settle, mapping)
        if out is not None:
            write_frame(frame, out)
        stats.add(frame)
        _summary(stats, f"{setpoints} ({len(frame)} rows)", _units(train))
    else:
        with contextlib.ExitStack() as stack:
            sink = None if out is None else stack.enter_context(frame_stream(out))
            wall, label = _run(train, duration, rate, dt, settle, quiet, stats, sink)
        _summary(stats, label, _units(train))
        console.print(wall)
    if out is not None:
        console.print(f"wrote {out}")


SIMULATE_CHUNK_S = 10.0
"""Machine time per piece of a ``simulate`` run: memory holds one piece, whatever the
duration (docs/mechanics.md gives the measured peak)."""


def _run(train: DriveTrain, duration: float, rate: float | None, dt: float | None,
         settle: float | None, quiet: bool, stats: RunningStats,
         sink: FrameStream | None) -> tuple[str, str]:  # fmt: skip
    """Simulate in pieces, each summarised and (with --out) written before the next."""
    from drafttwin.mechanics import simulate_chunks

    with progress_bar("simulating (machine s)", duration, quiet=quiet) as bar:
        task = bar.task_ids[0]
        stream = simulate_chunks(train, duration, chunk_s=SIMULATE_CHUNK_S, output_rate_hz=rate,
                                 dt_s=dt, settle_s=settle,
                                 progress=lambda s: bar.advance(task, s))  # fmt: skip
        for piece in stream:
            frame = _piece_frame(train, stream, piece)
            stats.add(frame)
            if sink is not None:
                sink.write(frame)
    compiled = f" (+{stream.compile_s:.1f} s kernel compilation)" if stream.compile_s > 0.5 else ""
    wall = (f"wall time {stream.wall_s:.2f} s{compiled}, real-time factor "
            f"{duration / stream.wall_s:.1f}x")  # fmt: skip
    return wall, f"{duration:g} s at {stream.rate_hz:g} Hz (dt {stream.dt_s:.2e} s)"


def _piece_frame(
    train: DriveTrain, stream: SimulationStream, piece: SimulationPiece
) -> pd.DataFrame:
    """``time`` and the rollers and motor (FA320A), or a train's own output channels."""
    if not stream.rollers:  # a train of your own: its output channels
        return pd.DataFrame({"time": piece.time_s, **{
            m.channel: m.from_rpm(piece.node_rpm[:, train.node_index(m.node)])
            for m in train.output_channels()}})  # fmt: skip
    cols = {"time": piece.time_s}
    for r in ROLLERS:
        if r in stream.rollers:
            cols[r] = piece.node_rpm[:, stream.rollers[r]]
    cols["motor"] = piece.node_rpm[:, stream.motor_node]
    return pd.DataFrame(cols)


def _follow(train: DriveTrain, path: Path, dt: float | None, settle: float | None,
            columns: dict[str, str] | None = None) -> pd.DataFrame:  # fmt: skip
    """The train simulated on a recorded file's grid, following its input columns (file
    columns renamed by ``columns``)."""
    from drafttwin.data.io import read_measurements
    from drafttwin.errors import ConfigError
    from drafttwin.mechanics import simulate as simulate_train

    names = tuple(c.channel for c in train.input_channels())
    if not names:
        raise ConfigError(
            f"the drive train {train.spec.train.name} maps no input channel to follow",
            where="--setpoints",
            fix="declare [[input]] tables in the drive-train file (see docs/mechanics.md)",
        )
    series = read_measurements(path, outputs=(), inputs=names, check_units=False, columns=columns)
    _check_supply(train, series, path)
    channels = [m.channel for m in train.output_channels()]
    kwargs: dict[str, Any] = {
        k: v for k, v in (("dt_s", dt), ("settle_s", settle)) if v is not None
    }
    parts = []
    for k, record in enumerate(series.records()):
        res = simulate_train(train, time_s=record.time_s, inputs=record.inputs, **kwargs)
        values = res.channels(channels)
        part = pd.DataFrame({"time": record.time_s, **dict(zip(channels, values.T, strict=True))})
        if series.n_records > 1:
            part["record"] = k + 1
        parts.append(part)
    return pd.concat(parts, ignore_index=True)


def _check_supply(train: DriveTrain, series: Any, path: Path) -> None:
    """A supply frequency below zero is refused (a VFD's set-point is not signed: the
    simulation would stand still); one far above the motor's rated supply is noted."""
    from drafttwin.errors import DataError

    rated = train.spec.motor.supply_hz if train.spec.motor is not None else None
    for c in train.input_channels():
        if c.drives != "supply_hz" or c.channel not in series.inputs:
            continue
        hz = c.gain * np.asarray(series.inputs[c.channel], dtype=np.float64) + c.offset
        if np.nanmin(hz) < 0:
            raise DataError(f"the supply frequency goes down to {np.nanmin(hz):.4g} Hz; a VFD's "
                            "set-point is not signed", source=path, where=f"column '{c.channel}'",
                            fix="give the set-point in Hz, 0 or above")  # fmt: skip
        if rated and np.nanmax(hz) > 2 * rated:
            err_console.print(f"note: {path.name}: the supply frequency reaches "
                              f"{np.nanmax(hz):.4g} Hz, {np.nanmax(hz) / rated:.1f} x the motor's "
                              f"rated {rated:g} Hz (is column '{c.channel}' in Hz?)",
                              highlight=False, soft_wrap=True)  # fmt: skip


def _units(train: DriveTrain) -> dict[str, str]:
    """Each written channel's unit: the train's output channels', rpm for the FA320A's rollers
    and motor (node speeds)."""
    return {"motor": "rpm", **{r: "rpm" for r in ROLLERS},
            **{m.channel: m.unit for m in train.output_channels()}}  # fmt: skip


def _summary(stats: RunningStats, label: str, units: dict[str, str]) -> None:
    table = Table(title=f"simulated: {label}")
    for col in ("channel", "unit", "mean", "std %", "peak-to-peak %"):
        table.add_column(col, justify="right" if col not in ("channel", "unit") else "left")
    for name, mean, std, ptp in stats.rows():
        scale = abs(mean) if mean else 1.0
        table.add_row(name, units.get(name, ""), f"{mean:.4g}", f"{std / scale * 100:.4f}",
                      f"{ptp / scale * 100:.4f}")  # fmt: skip
    console.print(table)
