"""The diagnosis of one record: alarm, ranked causes with severities, and the evidence.

    det = FaultDetector(far_per_day=1).fit([record_features(train, s) for s in healthy])
    dx = Diagnoser(train, det).diagnose(series)
    dx.alarm, dx.causes[0], dx.to_dict()

Sensor faults come first: a channel that loses samples on its own or repeats one value is
named as a sensor fault (never a machine element); an encoder gain error competes with the
machine candidates in the ranking, and its signature (one channel alone) is one no machine
fault can produce, because gears and chain are positive drives.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drafttwin.data.series import MeasurementSeries
from drafttwin.diagnosis.detect import Alarm, Detection, FaultDetector
from drafttwin.diagnosis.locate import (
    NOT_FROM_LEVELS,
    Cause,
    SignatureModel,
    creep_mismatch,
    rank_causes,
)
from drafttwin.diagnosis.residuals import CHANNELS, BlockFeatures, record_features
from drafttwin.diagnosis.spectrum import LineEvidence, line_evidence
from drafttwin.mechanics import DriveTrain

POST_S = 30.0  # s after the alarm used to measure the shift
MIN_BLOCKS = 5


@dataclass
class Diagnosis:
    """What :meth:`Diagnoser.diagnose` found in one record."""

    features: BlockFeatures
    detection: Detection
    causes: list[Cause] = field(default_factory=list)
    shift: np.ndarray | None = None  # relative level change per channel
    lines: list[LineEvidence] = field(default_factory=list)

    @property
    def alarm(self) -> Alarm | None:
        return self.detection.first

    def to_dict(self, top: int = 5) -> dict[str, Any]:
        a = self.alarm
        return {
            "alarm": None
            if a is None
            else {
                "time_s": a.time_s,
                "test": a.test,
                "direction": a.direction,
                "onset_s": a.change_s,
            },  # fmt: skip
            "shift_percent": None
            if self.shift is None
            else dict(zip(CHANNELS, (100 * self.shift).tolist(), strict=True)),
            "causes": [c.to_dict() for c in self.causes[:top]],
            "not_assessed_from_levels": list(NOT_FROM_LEVELS),
            "lines": [ln.to_dict() for ln in self.lines],
        }


class Diagnoser:
    """Detection, then localisation, on the physics ``train`` with a fitted detector.

    Args:
        model_mismatch: allow for the physics' belt creep being off on this machine (its
            relative error estimated from the detector's healthy records,
            :func:`~drafttwin.diagnosis.locate.creep_mismatch`) in the ranking's covariance.
    """

    def __init__(self, train: DriveTrain, detector: FaultDetector,
                 model_mismatch: bool = True) -> None:  # fmt: skip
        self.train, self.detector = train, detector
        self.signatures = SignatureModel(train)
        self.creep_rel_sd = (creep_mismatch(self.signatures, detector.belt_level_)
                             if model_mismatch else 0.0)  # fmt: skip

    def diagnose(self, series: MeasurementSeries) -> Diagnosis:
        """Detect, locate and size (with spectral evidence) in one record."""
        f = record_features(self.train, series, self.detector.block_s_)
        dx = self.from_features(f)
        if dx.alarm is not None:
            dx.lines = line_evidence(self.train, series, dx.alarm.change_s, dx.alarm.time_s)
        return dx

    def from_features(self, f: BlockFeatures) -> Diagnosis:
        """Detection and localisation from block features alone (no spectra)."""
        det = self.detector.run(f)
        dx = Diagnosis(f, det)
        alarm = det.first
        if alarm is None:
            return dx
        if alarm.direction == 0:  # a sensor rule: the channel is named, nothing else
            dx.causes = [sensor_cause(alarm, f.lost[alarm.block], f.run[alarm.block])]
            return dx
        base = det.baseline_at_alarm
        assert base is not None
        after = np.arange(len(f.level)) > alarm.block
        det.deviation[after] = f.level[after] - base  # evidence past the alarm, for the page
        # the shift after the alarm (a ramp has grown by then); the record up to the alarm
        # when too little follows it
        finite = np.isfinite(f.level).all(axis=1)
        window = (f.time_s > alarm.time_s) & (f.time_s <= alarm.time_s + POST_S) & finite
        if window.sum() < MIN_BLOCKS:
            window = (f.time_s > alarm.change_s) & (f.time_s <= alarm.time_s + POST_S) & finite
        if not window.any():
            return dx
        dx.shift = (f.level[window] - base).mean(axis=0)
        dx.causes = self.rank(dx.shift, int(window.sum()))
        return dx

    def rank(self, shift: np.ndarray, n_blocks: int) -> list[Cause]:
        """The candidates ranked for a level ``shift`` (5 channels) measured as the mean of
        ``n_blocks`` blocks (the live twin calls this on its post-alarm window)."""
        phi = float(self.detector.phi_[0])
        inflation = (1 + phi) / (1 - phi)
        cov = self.detector.level_cov_ * inflation / n_blocks
        return rank_causes(self.signatures, shift, cov, self.creep_rel_sd)


def sensor_cause(alarm: Alarm, lost: np.ndarray, run: np.ndarray) -> Cause:
    """The cause a sensor rule names: the channel, from its block's ``lost`` and ``run``."""
    rule, channel = alarm.test.split("_", 1)
    kind = "dropout" if rule == "lost" else "stuck"
    j = CHANNELS.index(channel)
    if kind == "dropout":
        sev = float(lost[j])
        parameter = "fraction of the channel's samples lost (in the alarm block)"
    else:
        sev = float(run[j])
        parameter = "identical consecutive values (samples, in the alarm block)"
    return Cause(channel, kind, "sensor", sev, (sev, sev), parameter, 0.0, 1.0, ())
