"""The study's data: one prepared set, shared by every task through a file.

* the split, preprocessing and scoring target of the evaluation protocol
  (:mod:`drafttwin.evaluation.protocol`): training part preprocessed as in the paper, test
  part cleaned causally, measured non-outlier test samples scored;
* the mechanistic prediction on the same grid, following the record's set-points (simulated
  once, cached by grid, set-points and preset);
* the same with the preset calibrated on the training part (``drafttwin calibrate``, reduced
  model in the loop; cached likewise), so the study can compare hybrids on nominal and on
  calibrated physics.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drafttwin.data.series import MeasurementSeries
from drafttwin.evaluation import protocol
from drafttwin.evaluation.protocol import Split
from drafttwin.execution import integrity
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
    mech_calibrated: np.ndarray | None = None  # (n, 4) rpm, calibrated on the training part

    @property
    def digest(self) -> str:
        extra = tuple(a for a in (self.true, self.mech_calibrated) if a is not None)
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
        if self.mech_calibrated is not None:
            arrays["mech_calibrated"] = self.mech_calibrated
        integrity.savez_sealed(path, **arrays)  # numbers only, atomic, with its sidecar
        return path

    @classmethod
    def load(cls, path: str | Path) -> PreparedData:
        """Read what :meth:`save` wrote; raises ``ValueError`` when the arrays disagree."""
        with np.load(path, allow_pickle=False) as z:
            data = cls(z["time_s"], z["inputs"], z["target"], z["mech"], z.get("true"),
                       int(z["n_train"]), z.get("mech_calibrated"))  # fmt: skip
        rows = len(data.time_s)
        arrays = (data.inputs, data.target, data.mech, data.true, data.mech_calibrated)
        if any(a is not None and a.shape != (rows, 4) for a in arrays) or not (
            0 < data.n_train < rows
        ):
            raise ValueError("prepared data arrays of inconsistent shapes")
        return data

    @classmethod
    def load_checked(cls, path: str | Path) -> PreparedData | None:
        """:meth:`load` when the file matches its sidecar; ``None`` (reported and discarded)
        when it is missing or damaged."""
        return integrity.read_checked(path, cls.load)

    def physics(self, which: str) -> np.ndarray:
        """The mechanistic prediction: ``nominal`` or ``calibrated``."""
        if which == "calibrated":
            if self.mech_calibrated is None:
                raise ValueError("these prepared data hold no calibrated physics")
            return self.mech_calibrated
        return self.mech


def _key(series: MeasurementSeries, preset: str, *extra: bytes) -> str:
    """Cache key of a simulation: grid, set-points, preset file, the code and anything else
    given."""
    from drafttwin.execution.store import code_fingerprint
    from drafttwin.mechanics.config import preset_path

    parts = [series.time_s.tobytes(), preset_path(preset).read_bytes(), *extra]
    parts.append(code_fingerprint().encode())
    parts += [k.encode() + v.tobytes() for k, v in sorted(series.inputs.items())]
    return hashlib.sha256(b"|".join(parts)).hexdigest()[:20]


def _mechanistic(series: MeasurementSeries, preset: str, cache_dir: Path) -> np.ndarray:
    """The preset simulated on the series' grid, following its set-points (cached by grid,
    set-points and preset file)."""
    from drafttwin.models import MechanisticModel

    cache = cache_dir / f"mechanistic-{preset}-{_key(series, preset)}.npy"
    cached = integrity.read_checked(cache, lambda p: integrity.load_array(p, series.values.shape))
    if cached is not None:
        return cached
    mech = MechanisticModel.from_preset(preset).predict_values(series)
    integrity.save_npy_sealed(cache, mech)
    return mech


def _load_report(path: Path) -> dict[str, Any]:
    """A calibration report written by :func:`_calibrated` (a JSON object)."""
    report = json.loads(path.read_text(encoding="utf-8"))
    if not isinstance(report, dict):
        raise ValueError("not a JSON object")
    return report


def _calibrated(
    series: MeasurementSeries, train: MeasurementSeries, preset: str, cache_dir: Path
) -> tuple[np.ndarray, dict[str, Any]]:
    """The preset calibrated on ``train`` (the preprocessed training part) and simulated on
    the whole series' grid, with the calibration's report (cached by grid, set-points,
    preset and training values)."""
    from drafttwin.calibration import calibrate
    from drafttwin.mechanics import DriveTrain, reduce
    from drafttwin.models import MechanisticModel

    key = _key(series, preset, b"calibrated", train.values.tobytes())
    cache = cache_dir / f"calibrated-{preset}-{key}"
    sim_path, report_path = cache.with_suffix(".npy"), cache.with_suffix(".json")
    cached_sim = integrity.read_checked(
        sim_path, lambda p: integrity.load_array(p, series.values.shape)
    )
    cached_report = integrity.read_checked(report_path, _load_report)
    if cached_sim is not None and cached_report is not None:
        return cached_sim, cached_report
    result = calibrate(DriveTrain.preset(preset), train, model=reduce, model_name="reduced")
    sim = MechanisticModel.from_train(result.train).predict_values(series)
    report = result.to_dict()
    integrity.save_npy_sealed(sim_path, sim)
    integrity.write_text_sealed(report_path, json.dumps(report, allow_nan=False))
    return sim, report


def prepare(
    series: MeasurementSeries,
    *,
    train_fraction: float,
    preset: str,
    cache_dir: Path,
    duration_s: float | None = None,
    calibrate: bool = True,
) -> tuple[PreparedData, dict[str, Any]]:
    """Split, preprocess, clean (the evaluation protocol), simulate (and calibrate the physics
    on the training part); returns the data and a summary for the report (with the
    calibration's report under ``calibration``)."""
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
    calibration = None
    if calibrate:
        assert part.train is not None
        data.mech_calibrated, calibration = _calibrated(series, part.train, preset, cache_dir)
    summary = {
        "rows": n,
        "rate_hz": series.sample_rate_hz,
        "duration_s": series.duration_s,
        "train_rows": n_train,
        "test_rows": n - n_train,
        "train_fraction": train_fraction,
        "scoring": SCORING,
        "preprocessing": part.summary["preprocessing"],
        "calibration": calibration,
    }
    return data, summary
