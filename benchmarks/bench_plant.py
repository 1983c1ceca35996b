"""Plant emulator and the default data set: generation time and the mechanistic baseline.

    python benchmarks/bench_plant.py

Times ``generate`` for 5 minutes at 100 Hz, and reports, on the default data set, how far the
nominal mechanistic model is from the plant (measured and true) and the encoders' own error
(measured vs true; the one-step floor is measured by
``python -m drafttwin.studies.accuracy_limits``).
Prints tables; writes benchmarks/results/plant.json.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))

from _machine import write_results  # noqa: E402
from drafttwin import ROLLERS  # noqa: E402
from drafttwin.data.preprocessing import preprocess  # noqa: E402
from drafttwin.datasets import load_default  # noqa: E402
from drafttwin.mechanics import DriveTrain, simulate  # noqa: E402
from drafttwin.plant import Plant  # noqa: E402


def baseline_table() -> list[dict]:
    series = load_default()
    truth = series.truth
    assert truth is not None  # the embedded data carry the true speeds
    clean, _ = preprocess(series)
    mech = simulate(DriveTrain.preset("fa320a"), time_s=series.time_s).roller_rpm()
    ok = ~np.isnan(series.values) & ~series.metadata["outlier_mask"]
    rows = []
    print(f"{'roller':8} {'mean rel %':>10} {'max rel %':>10} {'RMSE meas':>10} {'RMSE true':>10} "
          f"{'sensor err':>11} {'std(y)':>8}")  # fmt: skip
    for j, r in enumerate(ROLLERS):
        y, t, m = clean.values[:, j], truth[:, j], mech[:, j]
        rel = 100 * np.abs(y - m) / np.abs(y)
        row = {
            "roller": r,
            "mech_mean_rel_err_pct": float(rel.mean()),
            "mech_max_rel_err_pct": float(rel.max()),
            "mech_rmse_vs_measured_rpm": float(np.sqrt(np.mean((y - m) ** 2))),
            "mech_rmse_vs_true_rpm": float(np.sqrt(np.mean((t - m) ** 2))),
            "sensor_error_rmse_rpm": float(
                np.sqrt(np.mean((series.values[ok[:, j], j] - t[ok[:, j]]) ** 2))
            ),
            "sensor_error_after_preprocess_rpm": float(np.sqrt(np.mean((y - t) ** 2))),
            "std_measured_rpm": float(np.std(y)),
            "std_true_rpm": float(np.std(t)),
            "mean_offset_true_minus_mech_rpm": float(np.mean(t - m)),
        }
        rows.append(row)
        print(f"{r:8} {row['mech_mean_rel_err_pct']:>10.4f} {row['mech_max_rel_err_pct']:>10.4f} "
              f"{row['mech_rmse_vs_measured_rpm']:>10.3f} {row['mech_rmse_vs_true_rpm']:>10.3f} "
              f"{row['sensor_error_rmse_rpm']:>11.3f} {row['std_measured_rpm']:>8.3f}")  # fmt: skip
    return rows


def main() -> None:
    figures = []
    Plant().run(0.1, 100.0)  # compile
    start = time.perf_counter()
    rec = Plant().run(300.0, 100.0, seed=1)
    with tempfile.TemporaryDirectory() as tmp:
        rec.write(Path(tmp) / "plant.csv")
    wall = time.perf_counter() - start
    print(f"generate 5 min at 100 Hz (simulate + sensors + write CSV): {wall:.1f} s")
    figures.append(
        {"figure": "generate 300 s at 100 Hz, fa320a plant", "value": wall, "unit": "s wall"}
    )
    rows = baseline_table()
    for row in rows:
        for key, value in row.items():
            if key != "roller":
                unit = "%" if key.endswith("pct") else "rpm"
                figures.append(
                    {
                        "figure": f"default data, {row['roller']}: {key}",
                        "value": value,
                        "unit": unit,
                    }
                )
    print(f"wrote {write_results('plant', figures)}")


if __name__ == "__main__":
    main()
