"""``drafttwin kinematics`` and ``drafttwin simulate``: the mechanistic model."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.table import Table

from drafttwin.cli._common import check_output_suffix, load_train, write_frame
from drafttwin.cli.app import app, console, progress_bar

PresetOpt = Annotated[
    str | None, typer.Option("--preset", help="Built-in drive train (default: fa320a).")
]
ConfigOpt = Annotated[
    Path | None,
    typer.Option("--config", help="Drive-train TOML file (see docs/mechanics.md).", dir_okay=False),
]


@app.command()
def kinematics(
    preset: PresetOpt = None,
    config: ConfigOpt = None,
    motor_rpm: Annotated[
        float | None, typer.Option(help="Motor speed, rpm (default: the motor's rated speed).")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Nominal roller speeds, surface speeds, drafts, excitation and eigenfrequencies.

    Pure kinematics (rigid couplings, no slip, no creep): no simulation is run.
    """
    from drafttwin.mechanics import kinematics as compute
    from drafttwin.mechanics import operating_point

    train = load_train(preset, config)
    kin = compute(train, motor_rpm)
    if train.spec.motor is None:  # driven by external torques only: no running state
        typer.echo(json.dumps(kin.to_dict(), indent=2))
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
        typer.echo(json.dumps(out, indent=2))
        return
    table = Table(title=f"{train.spec.train.name}: nominal kinematics at {kin.motor_rpm:g} rpm")
    for col in ("roller", "diameter mm", "rpm", "surface m/min", "running rpm*"):
        table.add_column(col, justify="right" if col != "roller" else "left")
    for name, r in kin.rollers.items():
        table.add_row(name, f"{r.diameter_mm:g}", f"{r.rpm:.2f}", f"{r.surface_speed_m_min:.3f}",
                      f"{op.roller_rpm[name]:.2f}")  # fmt: skip
    console.print(table)
    console.print(f"delivery speed  {kin.delivery_speed_m_min:.2f} m/min")
    console.print("drafts          " + ", ".join(f"{k} {v:.4f}" for k, v in kin.drafts.items()))
    console.print(
        f"* running: torque balance with motor slip {op.slip * 100:.3f} % "
        f"({op.motor_rpm:.2f} rpm, {op.motor_torque_nm:.2f} N m) and belt creep "
        + ", ".join(f"{k} {v * 100:.4f} %" for k, v in op.belt_creep.items())
    )
    freqs = {**kin.mesh_frequencies_hz, **kin.chain_tooth_frequencies_hz}
    console.print("mesh / chain-tooth frequencies (Hz): "
                  + ", ".join(f"{k} {v:.1f}" for k, v in freqs.items()))  # fmt: skip
    console.print("torsional eigenfrequencies (Hz):     "
                  + ", ".join(f"{f:.1f}" for f in kin.eigenfrequencies_hz))  # fmt: skip


@app.command()
def simulate(
    preset: PresetOpt = None,
    config: ConfigOpt = None,
    duration: Annotated[float, typer.Option(help="Recorded machine time, s.", min=0)] = 10.0,
    rate: Annotated[float, typer.Option(help="Output rate, Hz (interval means).", min=0)] = 1000.0,
    dt: Annotated[float | None, typer.Option(help="RK4 step, s (default from config).")] = None,
    settle: Annotated[
        float | None, typer.Option(help="Settling time before recording, s (default from config).")
    ] = None,
    out: Annotated[
        Path | None, typer.Option(help="Write time + roller and motor rpm to .csv or .parquet.")
    ] = None,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
) -> None:
    """Simulate the drive train (numba RK4) and summarise the roller speeds.

    Speeds are means over each output interval, as an encoder reports them.
    """
    from drafttwin.mechanics import simulate as run

    train = load_train(preset, config)
    if out is not None:
        check_output_suffix(out)
    with progress_bar("simulating (machine s)", duration, quiet=quiet) as bar:
        task = bar.task_ids[0]
        res = run(train, duration, output_rate_hz=rate, dt_s=dt, settle_s=settle,
                  progress=lambda s: bar.advance(task, s))  # fmt: skip
    frame = res.to_frame()
    if out is not None:
        write_frame(frame, out)
    table = Table(
        title=f"{train.spec.train.name}: {duration:g} s at {rate:g} Hz (dt {res.dt_s:.2e} s)"
    )
    for col in ("roller", "mean rpm", "std %", "peak-to-peak %"):
        table.add_column(col, justify="right" if col != "roller" else "left")
    for name in [*res.rollers, "motor"]:
        x = frame[name].to_numpy()
        mean = float(np.mean(x))
        table.add_row(name, f"{mean:.3f}", f"{np.std(x) / mean * 100:.4f}",
                      f"{np.ptp(x) / mean * 100:.4f}")  # fmt: skip
    console.print(table)
    compiled = f" (+{res.compile_s:.1f} s kernel compilation)" if res.compile_s > 0.5 else ""
    console.print(f"wall time {res.wall_s:.2f} s{compiled}, real-time factor "
                  f"{duration / res.wall_s:.1f}x" + (f"; wrote {out}" if out else ""))  # fmt: skip
