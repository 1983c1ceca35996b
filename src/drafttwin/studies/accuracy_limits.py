"""Accuracy limits on the default data set: the encoders' own error, the one-step floor, and
two independent checks of the floor.

    python -m drafttwin.studies.accuracy_limits [--models]

On the test part of the default data set (the last 30 %, as the study scores it): the sensor
error (RMSE of measured vs true), its lag-one autocorrelation, the floor oracle's RMSE
(:func:`drafttwin.evaluation.accuracy_limits`), the closed form ``q * sqrt(1/12 + (C r s)^2)``
from the sensor settings (quantisation step q, C counts per revolution, r rev/s, clock jitter
s), a least-squares predictor of the sensor error from its last 32 values fitted on the first
70 % (an independent estimate of what a predictor can reach), and persistence. Prints a table;
writes benchmarks/results/limits.json.

``--models`` also fits persistence, the GRU, the parallel hybrid and MD-S-L on the first 70 % of
all 300 s (quick network sizes with a residual LSTM of 2 x 48, 30 epochs at a constant rate,
patience 5, seed 0; about 25 min on 2 shared cores) and scores them by the protocol: each
model's one-step RMSE against its floor (none may be below it) and its RMSE against the true
speed against the encoders' error; writes benchmarks/results/limits_models.json.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from drafttwin.data.preprocessing import DEFAULT_TRAIN_FRACTION
from drafttwin.datasets import load_default
from drafttwin.evaluation import accuracy_limits, floor_rows, protocol
from drafttwin.evaluation.limits import lag1_autocorrelation
from drafttwin.plant.config import PlantConfig
from drafttwin.plant.sensors import quantisation_step_rpm
from drafttwin.studies.figures import write_results

LAGS = 32
TRAIN_FRACTION = DEFAULT_TRAIN_FRACTION


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


def models_check() -> None:
    """Every model's one-step RMSE against its floor on all 300 s of the default data."""
    import torch

    from drafttwin.models import MechanisticModel, make_model

    torch.set_num_threads(1)
    data = load_default()
    physics = MechanisticModel.from_preset("fa320a")
    metrics, figures = {}, []
    for name in ("persistence", "gru", "parallel", "md-s-l"):
        t0 = time.perf_counter()
        kw = (
            {} if name == "persistence"
            else {"epochs": 30, "patience": 5, "schedule": "constant", "seed": 0, "quiet": True}
        )  # fmt: skip
        if name in ("parallel", "md-s-l"):  # the residual LSTM its figures were made with
            kw["layers"] = 2
        model = make_model(name, "quick", **kw)
        mech = physics if model.needs_mechanistic else None
        part = protocol.fit_split(model, data, train_fraction=TRAIN_FRACTION, mechanistic=mech)
        metrics[name] = protocol.evaluate(model, part, mechanistic=mech).metrics
        for c, m in metrics[name].items():
            print(f"{name:12} {c:7} RMSE {m.rmse:.4f} floor {m.rmse_floor:.4f} "
                  f"RMSE/floor {m.rmse / m.rmse_floor:.3f} vs true {m.rmse_vs_true:.4f} "
                  f"sensor {m.sensor_rmse:.4f} vs true/sensor {m.true_error_ratio:.3f}")  # fmt: skip
            for key in ("rmse", "rmse_floor", "rmse_vs_true", "sensor_rmse", "true_error_ratio"):
                figures.append({"figure": f"all 300 s, {name}, {c}: {key}",
                                "value": getattr(m, key),
                                "unit": "" if key == "true_error_ratio" else "rpm"})  # fmt: skip
        print(f"{name}: {time.perf_counter() - t0:.0f} s")
    for row in floor_rows(metrics):
        print(row)
        figures.append({"figure": f"all 300 s, {row['channel']}: models below the floor",
                        "value": len(row["below_floor"]), "unit": "count"})  # fmt: skip
    print(f"wrote {write_results('limits_models', figures)}")


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
    if "--models" in sys.argv[1:]:
        models_check()
