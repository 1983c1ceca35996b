"""The study's data: one prepared set, shared by every task through a file.

* the split, preprocessing and scoring target of the evaluation protocol
  (:mod:`drafttwin.evaluation.protocol`): training part preprocessed as in the paper, test
  part cleaned causally, measured non-outlier test samples scored;
* the mechanistic prediction on the same grid, following the record's set-points (simulated
  once, cached by grid, set-points and preset).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drafttwin.data.series import MeasurementSeries
from drafttwin.evaluation import protocol
from drafttwin.evaluation.protocol import Split
from drafttwin.execution.store import data_hash

SCORING = (
    "Scored: test-part samples that were measured and not flagged as outliers by the paper's "
    "rule (others are not scored). Model inputs: training part preprocessed as in the paper; "
    "test part cleaned causally (spikes > 10 % from the last accepted sample dropped, gaps "
    "held), so no prediction uses a future sample."
)


@dataclass
class PreparedData:
    time_s: np.ndarray
    inputs: np.ndarray  # (n, 4) rpm as the models see them, NaN = missing
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
        """The whole record as the models see it (training rows preprocessed, test rows
        cleaned causally), with the true speeds when known."""
        return MeasurementSeries(self.time_s, self.inputs, truth=self.true)

    def split(self) -> Split:
        """The protocol's chronological split of the prepared record."""
        whole = self.series()
        tr = self.n_train
        return Split(whole.slice(0, tr), whole.slice(tr), self.target[tr:], whole,
                     "chronological")  # fmt: skip

    def save(self, path: Path) -> Path:
        arrays = {"time_s": self.time_s, "inputs": self.inputs, "target": self.target,
                  "mech": self.mech, "n_train": np.array(self.n_train)}  # fmt: skip
        if self.true is not None:
            arrays["true"] = self.true
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, allow_pickle=False, **arrays)  # numbers only
        return path

    @classmethod
    def load(cls, path: str | Path) -> PreparedData:
        with np.load(path) as z:
            return cls(z["time_s"], z["inputs"], z["target"], z["mech"],
                       z.get("true"), int(z["n_train"]))  # fmt: skip


def _mechanistic(series: MeasurementSeries, preset: str, cache_dir: Path) -> np.ndarray:
    """The preset simulated on the series' grid, following its set-points (cached by grid,
    set-points and preset file)."""
    from drafttwin.mechanics.config import preset_path
    from drafttwin.models import MechanisticModel

    parts = [series.time_s.tobytes(), preset_path(preset).read_bytes()]
    parts += [k.encode() + v.tobytes() for k, v in sorted(series.inputs.items())]
    key = hashlib.sha256(b"|".join(parts)).hexdigest()[:20]
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
    """Split, preprocess, clean (the evaluation protocol), simulate; returns the data and a
    summary for the report."""
    if duration_s is not None:
        series = series.slice(0, int(np.searchsorted(series.time_s, series.time_s[0] + duration_s)))
    part = protocol.split(series, train_fraction=train_fraction)
    assert part.joined is not None
    n, n_train = len(series), len(series) - len(part.test_part())
    target = np.full(series.values.shape, np.nan)
    target[n_train:] = part.target
    data = PreparedData(
        time_s=series.time_s,
        inputs=part.joined.values,
        target=target,
        mech=_mechanistic(series, preset, cache_dir),
        true=series.truth,
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
        "preprocessing": part.summary["preprocessing"],
    }
    return data, summary
