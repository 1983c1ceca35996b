"""Stand-in measurements for the own-machine tutorial (docs/own-machine.md).

The belt drive of ``belt_drive.toml`` as it really runs: its parameters differ from the
drawing (a heavier process load, more bearing drag, a worn belt that creeps more), its load
fluctuates, and a logger samples the flywheel speed with noise and quantisation. The VFD
set-point ``u`` (V) steps between 4 and 9 V every few seconds. With a real machine you record
these files yourself; nothing else in the tutorial depends on how they were made.

Usage::

    python docs/examples/make_belt_records.py OUTDIR [--seed 0]

writes ``OUTDIR/train.csv`` (two experiments, told apart by a ``record`` column) and
``OUTDIR/test.csv`` (a third experiment), columns ``t`` (s), ``u`` (V), ``y`` (rad/s).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from drafttwin.mechanics import DriveTrain, Signal, simulate

HERE = Path(__file__).resolve().parent
RATE_HZ = 50.0
NOISE_RAD_S = 0.02  # logger noise (assumption)
STEP_RAD_S = 0.01  # logger resolution (assumption)


def true_machine() -> DriveTrain:
    """The drawing's belt drive with the parameters it really has (all assumptions)."""
    spec = DriveTrain.from_toml(HERE / "belt_drive.toml").to_dict()
    spec["bearing"][2]["coulomb_torque_nm"] = 2.5  # process load 25 % above the drawing's
    spec["bearing"][1]["viscous_nms"] = 0.004  # twice the windage and bearing drag
    spec["belt"][0]["axial_rigidity_n"] = 1.0e4  # a worn belt: 1.5x the creep
    return DriveTrain.from_dict(spec, source="true belt drive")


def record(duration_s: float, rng: np.random.Generator) -> pd.DataFrame:
    """One experiment: set-point steps, the true machine's response, the logger's reading."""
    n = int(duration_s * RATE_HZ)
    t = np.arange(1, n + 1) / RATE_HZ
    hold = rng.integers(int(2 * RATE_HZ), int(5 * RATE_HZ), size=n)
    u = np.empty(n)
    k = 0
    while k < n:
        u[k : k + hold[k]] = round(float(rng.uniform(4.0, 9.0)), 2)
        k += hold[k]
    ramp = Signal(0.0, 1.0 / RATE_HZ, 5.0 * np.r_[u[0], u], "zoh")  # Hz, held per sample
    wobble = 0.3 * np.sin(2 * np.pi * 0.7 * t + rng.uniform(0, 2 * np.pi))
    wobble += np.cumsum(rng.normal(0.0, 0.02, n))  # a load that drifts (assumption)
    load = Signal(0.0, 1.0 / RATE_HZ, np.r_[wobble[0], wobble], "zoh")
    machine = true_machine().with_supply_schedule(ramp).with_torque("flywheel", load)
    speed = simulate(machine, duration_s, output_rate_hz=RATE_HZ).node_rpm[:, 1] * np.pi / 30
    measured = speed + rng.normal(0.0, NOISE_RAD_S, n)
    return pd.DataFrame({"t": t, "u": u, "y": np.round(measured / STEP_RAD_S) * STEP_RAD_S})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="folder for train.csv and test.csv")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    args.out.mkdir(parents=True, exist_ok=True)
    train = pd.concat([record(40.0, rng).assign(record=k) for k in (1, 2)], ignore_index=True)
    train.to_csv(args.out / "train.csv", index=False, float_format="%.6g")
    record(30.0, rng).to_csv(args.out / "test.csv", index=False, float_format="%.6g")
    print(f"wrote {args.out / 'train.csv'} and {args.out / 'test.csv'}")


if __name__ == "__main__":
    main()
