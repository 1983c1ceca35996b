"""What a motor torque channel (a drive's current or torque estimate) would add to the
encoders, fault by fault.

The fault benchmark's misses with the encoders alone are load faults: bearing drags and
top-roller load losses change the transmitted torque, and the speeds only through the motor's
slip and the belt's creep. For every machine-element candidate of the diagnosis, at the
kind's moderate and severe level, :func:`sensitivities` sets side by side, from the physics'
operating point (torque balance, no integration):

* ``rollers_rel``: the relative change of the mean roller speed (what the encoders' common
  level sees) and its size in units of that stream's healthy block scale (``rollers_z``,
  measured on healthy plant records: ``sigma`` of the detector's ``rollers`` stream);
* ``motor_rel``: the motor speed's relative change;
* ``torque_rel``: the motor torque's relative change, and ``torque_z``: its size in units of
  the healthy block scale of the plant's true motor torque (the machine's own torque wander:
  drafting force, supply; the same definition as the speed stream's scale), i.e. what a
  noiseless torque or current channel would see; a real one adds its own noise.

Run: ``python -m drafttwin.studies.faults.torque_channel [--out FILE.json]`` (about 30 s:
two 100-s healthy plant records for the speed scale); docs/faults.md gives the table.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from drafttwin._io import write_text_atomic
from drafttwin.diagnosis.cusum import STREAMS
from drafttwin.diagnosis.detect import FaultDetector
from drafttwin.diagnosis.locate import ANGLE_KINDS, LEVEL_KINDS, SignatureModel
from drafttwin.diagnosis.residuals import record_features
from drafttwin.mechanics import DriveTrain, operating_point
from drafttwin.mechanics.faults import KINDS

LEVELS = ("moderate", "severe")


def healthy_scales(seconds: float = 100.0, machine_seed: int = 0) -> tuple[float, float]:
    """Healthy 1-s block scales (relative) of the mean roller level (``sigma`` of the
    detector's ``rollers`` stream) and of the true motor torque (SD of its block means'
    deviation from each record's first ``reference_s``, pooled), on two healthy plant
    records of one machine."""
    from drafttwin.plant import Machine, Plant

    plant = Plant()
    machine = Machine.draw(plant.train, plant.config, machine_seed)
    train = DriveTrain.preset("fa320a")
    records = [plant.run(seconds, seed=s, machine=machine) for s in (1, 2)]
    detector = FaultDetector().fit([record_features(train, r.series, 1.0) for r in records])
    n_ref = detector.reference_blocks(1.0)
    devs = []
    for r in records:
        torque = np.asarray(r.true_motor_torque_nm)
        blocks = torque[: len(torque) // 100 * 100].reshape(-1, 100).mean(axis=1)
        devs.append(blocks[n_ref:] / blocks[:n_ref].mean() - 1.0)
    return float(detector.sigma_[STREAMS.index("rollers")]), float(np.std(np.concatenate(devs)))


def sensitivities(train: DriveTrain, rollers_sigma: float,
                  torque_sigma: float) -> list[dict[str, Any]]:  # fmt: skip
    """One row per candidate and level (see the module)."""
    model = SignatureModel(train)
    base = operating_point(train)
    rows = []
    for element, kind in model.candidates:
        if kind not in LEVEL_KINDS + ANGLE_KINDS or kind == "gain":  # machine elements only
            continue
        for name, s in zip(LEVELS, KINDS[kind].levels[1:], strict=True):
            # an elongated chain's slack changes no torque balance: the healthy point
            op = (
                base
                if kind == "elongation"
                else operating_point(model.faulted_train(element, kind, s))
            )
            rollers = np.mean(
                [op.roller_rpm[r] / base.roller_rpm[r] - 1.0 for r in base.roller_rpm]
            )
            torque = op.motor_torque_nm / base.motor_torque_nm - 1.0
            rows.append({
                "cause": f"{element}:{kind}", "level": name, "severity": s,
                "parameter": KINDS[kind].parameter, "rollers_rel": float(rollers),
                "rollers_z": float(abs(rollers) / rollers_sigma),
                "motor_rel": float(op.motor_rpm / base.motor_rpm - 1.0),
                "torque_rel": float(torque), "torque_z": float(abs(torque) / torque_sigma),
            })  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=None, help="Write the rows as JSON here.")
    args = parser.parse_args(argv)
    rollers_sigma, torque_sigma = healthy_scales()
    rows = sensitivities(DriveTrain.preset("fa320a"), rollers_sigma, torque_sigma)
    print(f"healthy scales per 1-s block: rollers {rollers_sigma:.3g}, motor torque "
          f"{torque_sigma:.3g} (relative)")  # fmt: skip
    print(f"{'cause':32s} {'level':9s} {'rollers':>10s} {'z':>6s} {'motor':>10s} "
          f"{'torque':>8s} {'z':>6s}")  # fmt: skip
    for r in rows:
        print(f"{r['cause']:32s} {r['level']:9s} {r['rollers_rel']:10.2e} {r['rollers_z']:6.2f} "
              f"{r['motor_rel']:10.2e} {r['torque_rel']:8.2%} {r['torque_z']:6.1f}")  # fmt: skip
    if args.out is not None:
        result = {"rollers_sigma": rollers_sigma, "torque_sigma": torque_sigma, "rows": rows}
        write_text_atomic(args.out, json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
