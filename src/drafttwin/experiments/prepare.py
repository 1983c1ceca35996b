"""The study's data: one prepared set, shared by every task through a file.

* model inputs: the training part preprocessed as in the paper (interpolation, outlier
  smoothing: it may use the future, it is all in the past of the test part); the test part
  cleaned causally (spikes rejected using past samples only; gaps stay NaN and the models hold
  the last value), so no prediction sees the future;
* scoring target: the measured test samples that preprocessing did not flag (not missing, not
  an outlier by the paper's rule); everything else is not scored;
* the mechanistic prediction on the same grid (simulated once, cached by grid and preset).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drafttwin.data.preprocess import preprocess, reject_spikes_causal
from drafttwin.data.series import MeasurementSeries
from drafttwin.experiments.store import data_hash

SCORING = (
    "Scored: test-part samples that were measured and not flagged as outliers by the paper's "
    "rule (others are not scored). Model inputs: training part preprocessed as in the paper; "
    "test part cleaned causally (spikes > 10 % from the last accepted sample dropped, gaps "
    "held), so no prediction uses a future sample."
)


@dataclass
class PreparedData:
    time_s: np.ndarray
    inputs: np.ndarray  # (n, 4) rpm, NaN = missing
    target: np.ndarray  # (n, 4) rpm, NaN = not scored (whole training part included)
    mech: np.ndarray  # (n, 4) rpm
    true: np.ndarray | None  # (n, 4) rpm, plant truth
    n_train: int

    @property
    def digest(self) -> str:
        extra = () if self.true is None else (self.true,)
        return data_hash(self.time_s, self.inputs, self.target, self.mech, *extra,
                         np.array([self.n_train]))  # fmt: skip

    def series(self) -> MeasurementSeries:
        return MeasurementSeries(self.time_s, self.inputs)

    def save(self, path: Path) -> Path:
        arrays = {"time_s": self.time_s, "inputs": self.inputs, "target": self.target,
                  "mech": self.mech, "n_train": np.array(self.n_train)}  # fmt: skip
        if self.true is not None:
            arrays["true"] = self.true
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, **arrays)
        return path

    @classmethod
    def load(cls, path: str | Path) -> PreparedData:
        with np.load(path) as z:
            return cls(z["time_s"], z["inputs"], z["target"], z["mech"],
                       z.get("true"), int(z["n_train"]))  # fmt: skip


def _mechanistic(series: MeasurementSeries, preset: str, cache_dir: Path) -> np.ndarray:
    from drafttwin.mechanics.config import preset_path
    from drafttwin.models import MechanisticModel

    key = hashlib.sha256(series.time_s.tobytes() + preset_path(preset).read_bytes()).hexdigest()[
        :20
    ]
    cache = cache_dir / f"mechanistic-{preset}-{key}.npy"
    if cache.is_file():
        return np.load(cache)
    mech = MechanisticModel.from_preset(preset).predict(series)
    cache.parent.mkdir(parents=True, exist_ok=True)
    np.save(cache, mech)
    return mech


def prepare(
    series: MeasurementSeries,
    *,
    train_fraction: float,
    preset: str,
    cache_dir: Path,
    duration_s: float | None = None,
) -> tuple[PreparedData, dict]:
    """Split, preprocess, clean, simulate; returns the data and a summary for the report."""
    if duration_s is not None:
        series = series.slice(0, int(np.searchsorted(series.time_s, series.time_s[0] + duration_s)))
    n = len(series)
    n_train = int(round(train_fraction * n))
    clean_train, train_report = preprocess(series.slice(0, n_train))
    test_inputs, rejected = reject_spikes_causal(series.slice(n_train))
    _, full_report = preprocess(series)
    scored = ~np.isnan(series.values) & ~full_report.outliers
    scored[:n_train] = False
    target = np.where(scored, series.values, np.nan)
    true = series.metadata.get("true_rpm")
    data = PreparedData(
        time_s=series.time_s,
        inputs=np.vstack([clean_train.values, test_inputs]),
        target=target,
        mech=_mechanistic(series, preset, cache_dir),
        true=None if true is None else np.asarray(true, dtype=np.float64)[:n],
        n_train=n_train,
    )
    summary = {
        "rows": n,
        "rate_hz": series.sample_rate_hz,
        "duration_s": series.duration_s,
        "train_rows": n_train,
        "test_rows": n - n_train,
        "train_fraction": train_fraction,
        "scoring": SCORING,
        "preprocessing": {
            "train": train_report.to_dict(),
            "test_spikes_rejected_causally": int(rejected.sum()),
            "test_scored_samples": int(scored.sum()),
            "test_samples": int((n - n_train) * series.values.shape[1]),
        },
    }
    return data, summary
