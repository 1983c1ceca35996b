"""Accuracy limits on the default data set: the encoders' own error, the one-step floor, and
two independent checks of the floor.

    python benchmarks/bench_limits.py

On the test part of the default data set (the last 30 %, as the study scores it): the sensor
error (RMSE of measured vs true), its lag-one autocorrelation, the floor oracle's RMSE
(:func:`drafttwin.evaluation.accuracy_limits`), the closed form ``q * sqrt(1/12 + (C r s)^2)``
from the sensor settings (quantisation step q, C counts per revolution, r rev/s, clock jitter
s), a least-squares predictor of the sensor error from its last 32 values fitted on the first
70 % (an independent estimate of what a predictor can reach), and persistence. Prints a table;
writes benchmarks/results/limits.json.
"""

from __future__ import annotations

import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))

from _machine import write_results  # noqa: E402
from drafttwin.datasets import load_default  # noqa: E402
from drafttwin.evaluation import accuracy_limits  # noqa: E402
from drafttwin.evaluation.limits import lag1_autocorrelation  # noqa: E402
from drafttwin.plant.config import PlantConfig  # noqa: E402
from drafttwin.plant.sensors import quantisation_step_rpm  # noqa: E402

LAGS = 32
TRAIN_FRACTION = 0.7


def _fitted(e: np.ndarray, n_train: int) -> float:
    """Held-out RMSE of a least-squares predictor of ``e[t]`` from ``e[t-1..t-LAGS]``."""
    cols = [np.roll(e, k) for k in range(1, LAGS + 1)] + [np.ones_like(e)]
    x = np.column_stack(cols)
    x[:LAGS] = np.nan
    ok = np.isfinite(x).all(axis=1) & np.isfinite(e)
    rows = np.arange(e.size)
    fit, test = ok & (rows < n_train), ok & (rows >= n_train)
    coef, *_ = np.linalg.lstsq(x[fit], e[fit], rcond=None)
    return float(np.sqrt(np.mean((e[test] - x[test] @ coef) ** 2)))


def main() -> None:
    series = load_default()
    assert series.truth is not None  # the embedded data carry the true speeds
    measured = series.values.copy()
    measured[series.metadata["outlier_mask"]] = np.nan  # spikes are not scored
    true = series.truth
    n_train = int(round(TRAIN_FRACTION * len(measured)))
    limits = accuracy_limits(measured[n_train:], true[n_train:], channels=series.channels)
    sensors = PlantConfig().sensors
    rate = series.sample_rate_hz
    q = quantisation_step_rpm(sensors, rate)
    counts = sensors.pulses_per_rev * sensors.quadrature
    print(f"{'roller':8} {'sensor':>8} {'lag-1 ac':>9} {'floor':>8} {'closed':>8} "
          f"{'LS 32':>8} {'pers.':>8} {'floor/sensor':>12}")  # fmt: skip
    figures = []
    for j, c in enumerate(series.channels):
        e = measured[:, j] - true[:, j]
        rps = float(np.mean(true[n_train:, j])) / 60.0
        closed = q * np.sqrt(1 / 12 + (counts * rps * sensors.clock_jitter_s) ** 2)
        y = measured[n_train:, j]
        pers = float(np.sqrt(np.nanmean((y[1:] - y[:-1]) ** 2)))
        lim = limits[c]
        row = {
            "sensor_rmse": lim.sensor_rmse,
            "lag1_autocorrelation": lag1_autocorrelation(e[n_train:]),
            "floor": lim.floor,
            "floor_closed_form": float(closed),
            "ls32_heldout_rmse": _fitted(e, n_train),
            "persistence_rmse": pers,
            "floor_over_sensor": lim.floor / lim.sensor_rmse,
        }
        print(f"{c:8} {row['sensor_rmse']:>8.4f} {row['lag1_autocorrelation']:>9.3f} "
              f"{row['floor']:>8.4f} {row['floor_closed_form']:>8.4f} "
              f"{row['ls32_heldout_rmse']:>8.4f} {row['persistence_rmse']:>8.4f} "
              f"{row['floor_over_sensor']:>12.3f}")  # fmt: skip
        for key, value in row.items():
            unit = "" if key in ("lag1_autocorrelation", "floor_over_sensor") else "rpm"
            figures.append({"figure": f"default data test part, {c}: {key}", "value": value,
                            "unit": unit})  # fmt: skip
    print(f"wrote {write_results('limits', figures)}")


if __name__ == "__main__":
    main()
