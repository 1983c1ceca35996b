"""The benchmark's learned residuals: the data-driven model's and the parallel hybrid's.

Both are fitted once, on the healthy tuning records only (every machine of its own), and
then give every test record the same block features as the physics residual
(:func:`drafttwin.diagnosis.residuals.block_features`), so that one detector design (whitened
CUSUM, thresholds from the tuning features of that residual) compares the residuals alone:

* ``data-driven``: the paper's data-driven model, a GRU predicting the four rollers and the
  motor one step ahead from a window of their past measured values. Its residual is an
  innovation: a persistent change enters its own input window one sample later, so it shows
  only while the network has not caught up (research/faults.md, section 0 "Which residual").
  Its block shift says nothing about which element changed: it is not localised.
* ``hybrid``: the parallel hybrid in simulation mode (physics open loop from the set-points,
  plus an LSTM correction computed from the inputs and the simulated outputs only), so a
  fault cannot reach its prediction. It is localised like the physics (the shift of the five
  levels against the physics' candidate signatures).

The network sizes are fixed, small and chosen before any test record is seen (one fit of a
few seconds on 2 cores is shared by every record).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from drafttwin.data.series import MeasurementSeries
from drafttwin.diagnosis.residuals import CHANNELS, BlockFeatures, block_features, measured
from drafttwin.models import GRUModel, MechanisticModel, ParallelHybrid
from drafttwin.models.task import Task
from drafttwin.models.training import Training

LEARNED = ("data-driven", "hybrid")
WINDOW = 10  # samples: 0.1 s at 100 Hz
HIDDEN = 16
TRAINING = Training(epochs=20, batch_size=256, lr=3e-3, patience=4, val_fraction=0.2,
                    device="cpu")  # fmt: skip
INPUT = "supply_hz"


def raw_record(series: MeasurementSeries, physics: np.ndarray) -> dict[str, np.ndarray]:
    """What a learned residual needs of one record: times, the five measured channels, the
    set-point and the physics' open-loop prediction (float64 arrays)."""
    return {
        "time_s": series.time_s,
        "y": measured(series),
        INPUT: series.inputs[INPUT],
        "physics": physics,
    }


def _series(raw: dict[str, np.ndarray]) -> MeasurementSeries:
    return MeasurementSeries(np.asarray(raw["time_s"]), np.asarray(raw["y"]), channels=CHANNELS,
                             units=dict.fromkeys(CHANNELS, "rpm"),
                             inputs={INPUT: np.asarray(raw[INPUT])})  # fmt: skip


class LearnedResiduals:
    """Fit the data-driven and hybrid predictors on healthy records; block features of any
    record's residual against them.

    Args:
        block_s: block length of the features, s (the physics features' block).
        seed: weight initialisation and batch order of both networks.
    """

    def __init__(self, block_s: float, seed: int = 0) -> None:
        self.block_s, self.seed = block_s, seed

    def fit(self, healthy: Sequence[dict[str, np.ndarray]]) -> LearnedResiduals:
        """One fit of each network on all healthy tuning records together."""
        cat = MeasurementSeries.concat([_series(r) for r in healthy])
        physics = MechanisticModel(np.vstack([r["physics"] for r in healthy]), channels=CHANNELS)
        self.fit_s_: dict[str, float] = {}
        t0 = time.perf_counter()
        self.data_driven_ = GRUModel(WINDOW, HIDDEN, 1, 0.0, task=Task(outputs=CHANNELS),
                                     training=TRAINING, seed=self.seed, quiet=True).fit(cat)  # fmt: skip
        self.fit_s_["data-driven"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        # level target (no accumulation): the correction cannot drift away over a long record
        sim = Task(kind="simulation", inputs=(INPUT,), outputs=CHANNELS)
        self.hybrid_ = ParallelHybrid(WINDOW, HIDDEN, 1, 0.0, accumulate=False, task=sim,
                                      training=TRAINING, seed=self.seed, quiet=True)  # fmt: skip
        self.hybrid_.fit(cat, physics)
        self.fit_s_["hybrid"] = time.perf_counter() - t0
        return self

    def prediction(self, method: str, raw: dict[str, np.ndarray]) -> np.ndarray:
        """The method's prediction of the five channels, rpm, ``(n, 5)``."""
        series = _series(raw)
        if method == "data-driven":
            return self.data_driven_.predict_values(series)
        if method == "hybrid":
            physics = MechanisticModel(np.asarray(raw["physics"]), channels=CHANNELS)
            return self.hybrid_.predict_values(series, physics)
        raise ValueError(f"unknown learned method {method!r}")

    def features(self, method: str, raw: dict[str, np.ndarray],
                 physics: BlockFeatures | None = None) -> BlockFeatures:  # fmt: skip
        """Block features of the record's residual against the method's prediction; the
        angle lags, the stale runs judged by them, and which blocks are steady running from
        the physics. The lags measure the gears' positive drive through the kinematic ratio
        (a network's prediction has a ratio off by about 1e-4, and the lag then drifts by
        mrad per second: a healthy run of repeated readings then seems to move it, a stuck
        sensor); steady running is what the set-point commands (a one-step network's
        prediction follows the measured spikes past the steady band and cut a steady record
        into runs shorter than the reference window). ``physics``: the record's physics
        features when already computed (computed here otherwise)."""
        y, t = np.asarray(raw["y"]), np.asarray(raw["time_s"])
        f = block_features(y, self.prediction(method, raw), t, self.block_s)
        if physics is None:
            physics = block_features(y, np.asarray(raw["physics"]), t, self.block_s)
        return replace(f, lag=physics.lag, stale=physics.stale, steady=physics.steady)

    def describe(self) -> dict[str, Any]:
        """Sizes, training settings and fit results, JSON-able."""
        out: dict[str, Any] = {"window": WINDOW, "hidden": HIDDEN, "layers": 1,
                               "training": TRAINING.to_dict(), "seed": self.seed}  # fmt: skip
        for name, model in (("data-driven", self.data_driven_), ("hybrid", self.hybrid_)):
            h = model.history_
            out[name] = {"model": type(model).__name__, "task": model.task.kind,
                         "fit_s": self.fit_s_[name], "epochs": len(h.train_loss),
                         "best_epoch": h.best_epoch,
                         "val_loss": None if not h.val_loss else float(min(h.val_loss))}  # fmt: skip
        # what the hybrid's folds kept: its net, the measured offset held, or nothing
        out["hybrid"]["correction"] = self.hybrid_.selection_.get("correction")
        return out
