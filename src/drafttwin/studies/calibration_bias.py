"""Where a calibrated physics' bias on the test record comes from (a diagnostic of
:mod:`drafttwin.studies.calibration_accuracy`).

    python -m drafttwin.studies.calibration_bias [--seeds 101] [--train-s 60] [--test-s 120]
        [--method wander|plain|both] [--calibrate-on "full,no wander,quiet"]

For each machine seed the plant records the same three runs as ``calibration_accuracy`` (start-up
and steady for calibration, a speed change for the test; recording seeds 10 K + 1, 2, 3), and
again with recording-specific effects switched off in the plant's configuration, one after the
other, the machine and every other random stream unchanged (the plant draws one stream per
effect):

* ``full``: the plant as it is (its defaults are not changed here);
* ``no wander``: the supply's frequency wander off (``supply.jitter_hz = 0``);
* ``quiet``: also the drafting force's fluctuation (``drafting_force.cv = 0``; its mean stays)
  and the rollers' once-per-revolution load modulation off.

Reported per roller, on the test record, scored as ``drafttwin evaluate`` scores:

* the oracle's bias (the machine's own true train, as in ``calibration_accuracy``) on each
  variant of the test record: the differences are what the test record's own wander and
  drafting-force fluctuation put into its mean, which no calibration on other records can know;
* the oracle's shift from the rotor's warming between the calibration records' middle (the
  oracle's thermal state) and the test record's (noise-free, reduced model);
* the calibrated physics' bias (calibrated on each variant of the calibration records, tested on
  the full test record) and its split into the oracle's bias plus the parameter errors; the
  parameter errors split by group (slip, belt, load) by moving one group at a time from its true
  to its calibrated value (reduced model, noise-free simulation of the test record).

Writes benchmarks/results/calibrate_bias.json. The plant's defaults are never changed: the
variants are diagnostic configurations only.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

import drafttwin as dt
from drafttwin._constants import ROLLERS
from drafttwin.calibration import Calibration, Parameter, calibrate, select, with_factors
from drafttwin.mechanics import DriveTrain, reduce, simulate
from drafttwin.plant import Machine, Plant, PlantConfig
from drafttwin.plant.config import DraftingForce, Eccentricity, Supply
from drafttwin.studies.calibration_accuracy import errors, thermal_factor, truth
from drafttwin.studies.figures import write_results


def variants() -> dict[str, PlantConfig]:
    full = PlantConfig()
    no_wander = full.model_copy(update={"supply": Supply(jitter_hz=0.0)})
    quiet = no_wander.model_copy(update={
        "drafting_force": DraftingForce(cv=0.0),
        "eccentricity": Eccentricity(roller_load_modulation=0.0),
    })  # fmt: skip
    return {"full": full, "no wander": no_wander, "quiet": quiet}


def record(
    seed: int, cfg: PlantConfig, machine: Machine, args: argparse.Namespace, folder: Path, tag: str
) -> tuple[dt.MeasurementSeries, dt.MeasurementSeries]:
    runs = {"startup": (10 * seed + 1, args.train_s), "steady": (10 * seed + 2, args.train_s),
            "speed-change": (10 * seed + 3, args.test_s)}  # fmt: skip
    plant = Plant(config=cfg)
    paths = {}
    for scenario, (rec_seed, duration) in runs.items():
        rec = plant.run(duration, 100.0, seed=rec_seed, scenario=scenario, machine=machine)
        name = f"m{seed}_{tag.replace(' ', '_')}_{scenario}.parquet"
        paths[scenario] = rec.write(folder / name)[0]
    data = dt.read_measurements([paths["startup"], paths["steady"]])
    return data, dt.read_measurements(paths["speed-change"])


def mean_front_shift(a: DriveTrain, b: DriveTrain, test: dt.MeasurementSeries) -> float:
    """Mean front-roller speed of ``b`` minus ``a`` over the test record (reduced model)."""
    sims = [simulate(reduce(t), time_s=test.time_s, inputs=test.inputs).channels(ROLLERS)
            for t in (a, b)]  # fmt: skip
    return float(np.mean(sims[1][:, 0] - sims[0][:, 0]))


def split(
    cal: Calibration,
    oracle_factors: np.ndarray,
    chosen: list[Parameter],
    nominal: DriveTrain,
    test: dt.MeasurementSeries,
) -> dict[str, float]:
    """The calibrated-minus-oracle front-roller shift on the test record, one free group at a
    time moved from its true to its calibrated factors, and all together."""
    est = np.array([e.factor for e in cal.estimates])
    oracle = with_factors(nominal, chosen, oracle_factors)
    out: dict[str, float] = {}
    groups: dict[str, list[int]] = {}
    for i, e in enumerate(cal.estimates):
        if e.verdict in ("identified", "only in combination"):
            key = e.name if e.verdict == "identified" else "load combination"
            groups.setdefault(key, []).append(i)
    for key, members in groups.items():
        f = oracle_factors.copy()
        f[members] = est[members]
        out[key] = mean_front_shift(oracle, with_factors(nominal, chosen, f), test)
    left = [i for i in range(len(chosen)) if all(i not in m for m in groups.values())]
    f = oracle_factors.copy()
    f[left] = est[left]  # the parameters left at nominal (truth drawn, model nominal)
    out["left at nominal"] = mean_front_shift(oracle, with_factors(nominal, chosen, f), test)
    out["all"] = mean_front_shift(oracle, with_factors(nominal, chosen, est), test)
    return out


def one_machine(seed: int, args: argparse.Namespace, folder: Path) -> dict[str, Any]:
    nominal = Plant().train
    machine = Machine.draw(nominal, PlantConfig(), seed)
    chosen = select(nominal, None)
    true = truth(machine, PlantConfig(), 0.5 * args.train_s)
    oracle_f = np.array([true.get(p.name, 1.0) for p in chosen])
    oracle = with_factors(nominal, chosen, oracle_f)
    records = {tag: record(seed, cfg, machine, args, folder, tag)
               for tag, cfg in variants().items()}  # fmt: skip
    test = records["full"][1]
    row: dict[str, Any] = {"machine_seed": seed, "oracle_bias": {}, "calibrations": []}
    warm = oracle_f.copy()
    warm[[p.name for p in chosen].index("motor.rated_slip")] = thermal_factor(
        PlantConfig(), 0.5 * args.test_s
    )
    row["thermal_shift_front"] = mean_front_shift(oracle, with_factors(nominal, chosen, warm), test)
    print(f"m{seed} oracle front shift, thermal state of the test record: "
          f"{row['thermal_shift_front']:+.4f}")  # fmt: skip
    for tag, (_, test_v) in records.items():
        row["oracle_bias"][tag] = errors(oracle, records["full"][0], test_v)[0].tolist()
        print(f"m{seed} oracle bias, test record {tag}: {np.round(row['oracle_bias'][tag], 4)}")
    methods = {"wander": ("motor",), "plain": ()}
    chosen_methods = list(methods) if args.method == "both" else [args.method]
    for tag, (data, _) in records.items():
        if tag not in args.calibrate_on.split(","):
            continue
        for method in chosen_methods:
            cal = calibrate(nominal, data, model=reduce, model_name="reduced",
                            coloured=methods[method])  # fmt: skip
            bias = errors(cal.train, data, test)[0]
            parts = split(cal, oracle_f, chosen, nominal, test)
            factors = {e.name if e.verdict == "identified" else "load combination": e.factor
                       for e in cal.estimates if e.verdict in ("identified", "only in combination")}  # fmt: skip
            item = {"calibration_records": tag, "method": method, "test_bias": bias.tolist(),
                    "front_shift_vs_oracle": parts, "factors": factors,
                    "residual_model": cal.residual_model}  # fmt: skip
            row["calibrations"].append(item)
            print(f"m{seed} calibrated on {tag} records, {method}: test bias "
                  f"{np.round(bias, 4)}; front shift vs oracle "
                  + ", ".join(f"{k} {v:+.4f}" for k, v in parts.items())
                  + "; factors " + ", ".join(f"{k.split('.')[-1]} {v:.3f}"
                                             for k, v in factors.items()))  # fmt: skip
    row["true_factors"] = {"motor.rated_slip": true["motor.rated_slip"],
                           "belt.main_belt.axial_rigidity_n": true.get(
                               "belt.main_belt.axial_rigidity_n", float("nan"))}  # fmt: skip
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="101", help="machine seeds, comma-separated")
    parser.add_argument("--train-s", type=float, default=60.0)
    parser.add_argument("--test-s", type=float, default=120.0)
    parser.add_argument("--method", choices=("wander", "plain", "both"), default="both")
    parser.add_argument("--calibrate-on", default="full,no wander,quiet",
                        help="which variants of the calibration records to calibrate on")  # fmt: skip
    args = parser.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        rows = [one_machine(s, args, Path(tmp)) for s in seeds]
    figures = []
    for row in rows:
        k = row["machine_seed"]
        figures.append({"figure": f"machine {k}: oracle front-roller shift from the test "
                                  "record's thermal state", "value": row["thermal_shift_front"],
                        "unit": "rpm"})  # fmt: skip
        for tag, bias in row["oracle_bias"].items():
            figures.append({"figure": f"machine {k}: oracle test bias, test record {tag}",
                            "value": dict(zip(ROLLERS, bias, strict=True)), "unit": "rpm"})  # fmt: skip
        for c in row["calibrations"]:
            figures.append({"figure": f"machine {k}: calibrated ({c['method']}) on "
                                      f"{c['calibration_records']} records, test bias",
                            "value": dict(zip(ROLLERS, c["test_bias"], strict=True)),
                            "unit": "rpm"})  # fmt: skip
            figures.append({"figure": f"machine {k}: calibrated ({c['method']}) on "
                                      f"{c['calibration_records']} records, front-roller shift "
                                      "against the oracle by parameter group",
                            "value": c["front_shift_vs_oracle"], "unit": "rpm"})  # fmt: skip
    suffix = "" if seeds == [101] else "_" + "_".join(map(str, seeds))
    print(f"wrote {write_results('calibrate_bias' + suffix, figures)}")


if __name__ == "__main__":
    main()
