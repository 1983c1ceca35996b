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

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.linalg import block_diag

from drafttwin.data.series import MeasurementSeries
from drafttwin.diagnosis.blocks import check_rows_per_block
from drafttwin.diagnosis.cusum import STREAMS, Alarm, feature_matrix
from drafttwin.diagnosis.detect import Detection, FaultDetector
from drafttwin.diagnosis.growth import block_severities, severity_trend
from drafttwin.diagnosis.locate import (
    ANGLE_KINDS,
    NOT_ASSESSED,
    Cause,
    SignatureModel,
    creep_mismatch,
    explained,
    rank_causes,
)
from drafttwin.diagnosis.residuals import (
    CHANNELS,
    LAGGED,
    BlockFeatures,
    measured,
    physics_prediction,
    roller_ratio,
    runs_of,
)
from drafttwin.diagnosis.sensors import size_sensor_fault
from drafttwin.diagnosis.spectrum import LineEvidence, line_evidence
from drafttwin.diagnosis.stream import (
    POST_S,
    Decisions,
    DiagnosisStream,
    RankRequest,
    Step,
    decide,
)
from drafttwin.diagnosis.walk import baseline_weights, walk_covariance
from drafttwin.errors import DataError
from drafttwin.mechanics import DriveTrain


@dataclass
class Diagnosis:
    """What :meth:`Diagnoser.diagnose` found in one record."""

    features: BlockFeatures
    detection: Detection
    causes: list[Cause] = field(default_factory=list)
    shift: np.ndarray | None = None  # relative level change per channel, then lags (mrad)
    lines: list[LineEvidence] = field(default_factory=list)
    ranked: Alarm | None = None  # the alarm whose causes these are (default: the first)

    @property
    def alarm(self) -> Alarm | None:
        return self.ranked if self.ranked is not None else self.detection.first

    @property
    def verdict(self) -> str | None:
        """In words: which cause explains the shift, or that none of the candidates does
        (None without ranked causes)."""
        if not self.causes:
            return None
        if not explained(self.causes):
            best = self.causes[0]
            return (f"no candidate explains this (the best, {best.name}, misfits with chi2 "
                    f"{best.chi2:.4g} on {best.dof} degrees of freedom)")  # fmt: skip
        first = next(c for c in self.causes if c.fits)
        lo, hi = first.interval
        if first.bound is None and lo <= 0.0 <= hi:  # a fit of no size: no fault named
            return (f"no cause sized above zero: the best fit, {first.name}, is "
                    f"{first.severity:.4g} [{lo:.4g}, {hi:.4g}], which holds no fault")  # fmt: skip
        grows = first.growth is not None and first.growth.growing
        return f"explained by {first.name}" + (", still growing" if grows else "")

    def not_steady_s(self) -> list[tuple[float, float]]:
        """The stretches (start, end, s) of blocks that were not steady running (a start, a
        stop, a speed change: :func:`~drafttwin.diagnosis.blocks.commanded_steady`), which
        the detector did not judge."""
        f = self.features
        return [(float(f.time_s[a] - f.block_s), float(f.time_s[b - 1]))
                for a, b in runs_of(~f.steady_blocks)]  # fmt: skip

    def watched_from_s(self, reference_s: float) -> float | None:
        """When the detector began to decide: the first steady block's start plus the
        reference window (``None``: never steady)."""
        f = self.features
        steady = np.flatnonzero(f.steady_blocks)
        if not steady.size:
            return None
        return float(f.time_s[steady[0]] - f.block_s + reference_s)

    def judged(self, reference_s: float) -> bool:
        """Whether any block was judged: steady running past the reference window."""
        start = self.watched_from_s(reference_s)
        return start is not None and bool(self.features.time_s[-1] > start)

    def short_note(self, reference_s: float) -> str | None:
        """A line for the user when nothing was judged (no steady running past the reference
        window), else ``None``: "no alarm" would read as a healthy verdict."""
        if self.judged(reference_s):
            return None
        f = self.features
        return (
            f"nothing was judged: the record ({f.time_s[-1] - f.time_s[0] + f.block_s:.0f} "
            f"s) holds no steady running past the {reference_s:g}-s reference window; give "
            "a longer record"
        )

    def steady_note(self, reference_s: float) -> str | None:
        """A line for the user when parts of the record were not judged, else ``None``."""
        spans = self.not_steady_s()
        if not spans:
            return None
        where = ", ".join(f"{a:.1f}-{b:.1f} s" for a, b in spans[:3])
        if len(spans) > 3:
            where += f" and {len(spans) - 3} more"
        return (f"not judged where the set-point did not hold the machine at a steady speed "
                f"(a start, a stop or a speed change: {where}); the thresholds hold for "
                f"steady running, and each steady stretch after one is watched after its own "
                f"{reference_s:g}-s reference window")  # fmt: skip

    def to_dict(self, top: int = 5) -> dict[str, Any]:
        a = self.alarm
        return {
            "alarm": None
            if a is None
            else {
                "time_s": a.time_s,
                "test": a.test,
                "rule": a.rule,
                "direction": a.direction,
                "onset_s": a.change_s,
            },  # fmt: skip
            "shift_percent": None
            if self.shift is None
            else dict(zip(CHANNELS, (100 * self.shift[: len(CHANNELS)]).tolist(), strict=True)),
            "lag_shift_mrad": None  # over the last part of the window
            if self.shift is None
            else dict(zip(LAGGED, self.shift[-len(LAGGED) :].tolist(), strict=True)),
            "verdict": self.verdict,
            "explained": None if not self.causes else explained(self.causes),
            "probability_is": "relative: among the ranked candidates, summing to 1; whether a "
            "cause fits at all is its fit_p (chi2 on dof)",
            "causes": [c.to_dict() for c in self.causes[:top]],
            "not_assessed": list(NOT_ASSESSED),
            "lines": [ln.to_dict() for ln in self.lines],
            "not_steady_s": [list(span) for span in self.not_steady_s()],
        }


class Diagnoser:
    """Detection, then localisation, on the physics ``train`` with a fitted detector: a
    record pushed through a :class:`~drafttwin.diagnosis.stream.DiagnosisStream` (the live
    twin's own), its first alarm's window ranked.

    Args:
        model_mismatch: allow for the physics' belt creep being off on this machine (its
            relative error estimated from the detector's healthy records,
            :func:`~drafttwin.diagnosis.locate.creep_mismatch`) in the ranking's covariance.
        post_s: the window after an alarm whose shift is ranked, s.
        signatures: the train's :class:`~drafttwin.diagnosis.locate.SignatureModel`, when one
            is at hand (it is the costly part; machines of one train share it).
    """

    def __init__(self, train: DriveTrain, detector: FaultDetector, model_mismatch: bool = True,
                 post_s: float = POST_S, signatures: SignatureModel | None = None) -> None:  # fmt: skip
        self.train, self.detector, self.post_s = train, detector, post_s
        self.signatures = SignatureModel(train) if signatures is None else signatures
        self.creep_rel_sd = (creep_mismatch(self.signatures, detector.belt_level_)
                             if model_mismatch else 0.0)  # fmt: skip

    def stream(self, period_s: float, *, trace: bool = False, machine: str = "") -> DiagnosisStream:
        """A stream of this diagnosis for rows every ``period_s`` seconds."""
        return DiagnosisStream(period_s, roller_ratio(self.train), detector=self.detector,
                               post_s=self.post_s, trace=trace, machine=machine)  # fmt: skip

    def diagnose(self, series: MeasurementSeries, first_after: float | None = None) -> Diagnosis:
        """Detect, locate and size (with spectral evidence) in one record; ``first_after``:
        rank the first alarm at or after this time (s) instead of the record's first (the
        end of a part of the record that set the thresholds)."""
        t = np.asarray(series.time_s, dtype=np.float64)
        if len(t) < 2:
            raise DataError("the record has fewer than two samples", where="data",
                            fix="give a longer record")  # fmt: skip
        check_rows_per_block(self.detector.block_s_, float(np.median(np.diff(t))))
        stream = self.stream(float(np.median(np.diff(t))), trace=True)
        step = stream.push(t, measured(series), physics_prediction(self.train, series))
        step += stream.finish()
        if not stream.rows:
            raise DataError(f"the record is shorter than one block ({self.detector.block_s_:g} s)",
                            where="data", fix="give a longer record")  # fmt: skip
        f = BlockFeatures.from_rows(stream.rows, stream.blocks.block_s)
        assert stream.decisions is not None
        dx = self._diagnosis(f, stream.decisions, step, first_after)
        a = dx.alarm
        if a is not None:
            dx.lines = line_evidence(self.train, series, a.change_s, a.time_s)
        return dx

    def from_features(self, f: BlockFeatures, first_after: float | None = None) -> Diagnosis:
        """Detection and localisation from block features alone (no spectra, no sensor
        sizing on samples); ``first_after``: rank the first alarm at or after this time (a
        benchmark's onset) instead of the record's first."""
        decisions, step = decide(self.detector, f, post_s=self.post_s, trace=True)
        return self._diagnosis(f, decisions, step, first_after)

    def _diagnosis(self, f: BlockFeatures, decisions: Decisions, step: Step,
                   first_after: float | None = None) -> Diagnosis:  # fmt: skip
        """The record's first alarm (at or after ``first_after``) and its window's causes."""
        det = decisions.detection()
        later = [a for a in det.alarms if first_after is None or a.time_s >= first_after]
        alarm = later[0] if later else None
        dx = Diagnosis(f, det, ranked=alarm)
        if alarm is None:
            return dx
        req = next((r for r in step.requests if r.alarm == alarm), None)
        if req is None:
            return dx
        det.baseline_at_alarm = req.base
        after = np.arange(len(f.time_s)) > alarm.block
        det.deviation[after] = feature_matrix(f)[after] - req.base  # the evidence, for the page
        dx.shift, dx.causes = self.locate(req)
        return dx

    def locate(self, req: RankRequest) -> tuple[np.ndarray | None, list[Cause]]:
        """The causes of a window (:class:`~drafttwin.diagnosis.stream.RankRequest`), the best
        first, with the shift they explain; a sensor rule's window: its channel, sized on the
        samples when the request carries them. The live twin calls this in its worker."""
        if req.sensor is not None:
            return None, [self._sensor_cause(req)]
        if req.n_blocks == 0:
            return None, []
        shift, causes = self.rank(req.time_s, req.blocks, req.deviation, req.alarm.change_s,
                                  req.alarm.block)  # fmt: skip
        # the trend of the cause the verdict names: the first that fits, else the first
        i = next((i for i, c in enumerate(causes) if c.fits), 0)
        if causes:
            causes[i] = self._with_growth(causes[i], req)
        return shift, causes

    def _sensor_cause(self, req: RankRequest) -> Cause:
        assert req.sensor is not None and req.sensor_window is not None
        channel, kind = req.sensor
        w = req.sensor_window
        named = Alarm(w.time_s, w.block, f"{'lost' if kind == 'dropout' else 'stuck'}_{channel}",
                      0, w.time_s - req.block_s, "sensor")  # fmt: skip
        period = None
        if req.raw_time_s is not None and len(req.raw_time_s) > 1:
            period = float(np.median(np.diff(req.raw_time_s)))
        cause = sensor_cause(named, w.lost, w.run, None if period is None else 1.0 / period)
        if req.raw_y is None or req.raw_time_s is None or period is None:
            return cause
        j = CHANNELS.index(channel)
        healthy_run = float(self.detector.run_limit_[j]) / 2  # the longest in tuning
        return size_sensor_fault(req.raw_time_s, req.raw_y, cause, w.time_s,
                                 min(req.alarm.change_s, named.change_s), req.block_s,
                                 healthy_run)  # fmt: skip

    def _with_growth(self, cause: Cause, req: RankRequest) -> Cause:
        """``cause`` with the trend of its severity over the window
        (:mod:`drafttwin.diagnosis.growth`)."""
        finite = np.isfinite(req.deviation).all(axis=1)
        if not finite.any():
            return cause
        dev, t = req.deviation[finite], req.time_s[finite]
        det = self.detector
        sev = block_severities(self.signatures, cause, dev, det.feature_cov_)
        lag0 = STREAMS.index(f"lag_{LAGGED[0]}")
        phi = det.phi_[lag0:] if cause.kind in ANGLE_KINDS else det.phi_[:lag0]
        mid = t - req.block_s / 2
        growth = severity_trend(sev, mid, float(np.max(phi)), 1.0 if cause.severity >= 0 else -1.0)
        if growth is None:
            return cause
        # the block scatter does not see the model's own error (a machine's belt creep off
        # the physics' scales every block alike): add the ranked interval's half width,
        # scaled to the severity at the end
        half_rank = (cause.interval[1] - cause.interval[0]) / 2
        scale = abs(growth.severity / cause.severity) if cause.severity != 0 else 1.0
        stat = (growth.interval[1] - growth.interval[0]) / 2
        half = float(np.hypot(stat, half_rank * max(1.0, scale)))
        at_end = (growth.severity - half, growth.severity + half)
        return replace(cause, growth=replace(growth, interval=at_end))

    def rank(self, time_s: np.ndarray, blocks: np.ndarray, dev: np.ndarray,
             change_s: float, alarm_block: int | None = None) -> tuple[np.ndarray, list[Cause]]:  # fmt: skip
        """The shift (see :meth:`_shift`) of the window's blocks (their end times, their
        indices, their features minus the baseline at the alarm, raised at ``alarm_block``:
        default the block before the window) and the candidates ranked for it; the live
        twin calls this on its post-alarm window."""
        end = int(blocks[0]) if alarm_block is None else int(alarm_block) + 1
        shift, cov, elapsed = self._shift(time_s, dev, blocks, change_s, end)
        self.signatures.elapsed_s = elapsed
        # the absolute fit judges the lags only where the tuning records measured their slow
        # wander (the detector watches them); else their noise is underestimated several fold
        judged = np.arange(len(shift)) < len(CHANNELS) if not self.detector.lags_watched else None
        return shift, rank_causes(self.signatures, shift, cov, self.creep_rel_sd, judged)

    def _shift(self, time_s: np.ndarray, dev: np.ndarray, blocks: np.ndarray, change_s: float,
               base_end: int) -> tuple[np.ndarray, np.ndarray, dict[str, tuple[float, ...]]]:  # fmt: skip
        """The shift vector (mean levels over the window, then the mean lags over each half
        of it), its covariance, and per roller each half's mean time since the change an
        encoder gain on that roller would have run for (:func:`_gain_start`). The lags'
        covariance holds their random walk (:mod:`~drafttwin.diagnosis.walk`) between the
        baseline (formed over the blocks before ``base_end``) and each half."""
        det, nc = self.detector, len(CHANNELS)
        halves = np.array_split(np.arange(len(blocks)), 2) if len(blocks) >= 2 else [np.arange(1)]
        phi = det.phi_
        # levels: the covariance of a mean of AR(1) blocks, variance x (1 + phi)/(1 - phi)/n
        cov_l = det.level_cov_ * (1 + phi[0]) / (1 - phi[0]) / len(blocks)
        # lags: AR(1) covariances between the halves' means (a lag wanders slowly, so the
        # halves are correlated), with the lag streams' mean phi: Kronecker product of the
        # halves' correlation and the healthy lag covariance, positive definite by
        # construction
        lag0 = STREAMS.index(f"lag_{LAGGED[0]}")
        rho = float(np.mean(phi[lag0 : lag0 + len(LAGGED)]))
        t = blocks.astype(float)
        parts = np.array([[np.mean(rho ** np.abs(t[ha][:, None] - t[hb][None, :]))
                           for hb in halves] for ha in halves])  # fmt: skip
        base = baseline_weights(base_end, det.reference_blocks(det.block_s_), det.drift_alpha)
        walk = walk_covariance([blocks[h] for h in halves], base)
        cov = block_diag(cov_l, np.kron(parts, det.feature_cov_[nc:, nc:])
                         + np.kron(walk, det.lag_walk_))  # fmt: skip
        shift = np.concatenate([dev[:, :nc].mean(axis=0),
                                *(dev[h, nc:].mean(axis=0) for h in halves)])  # fmt: skip
        t = np.asarray(time_s, dtype=np.float64)
        elapsed = {}
        for j, ch in enumerate(CHANNELS[:4]):  # a front gain moves every lag: take the first
            start = _gain_start(t, dev[:, nc + max(j - 1, 0)], change_s)
            elapsed[ch] = tuple(float(np.mean(t[h] - start)) for h in halves)
        return shift, cov, elapsed


def _gain_start(t: np.ndarray, lag: np.ndarray, change_s: float) -> float:
    """When an encoder gain error would have started for the lag to grow as observed: the
    time a straight line through the window's lag crosses zero (a ramp counts from about
    its middle, possibly after the alarm), kept between the detector's change estimate and
    the window's end."""
    hi = float(t[-1]) if len(t) else change_s
    if len(t) < 2 or np.ptp(t) == 0:
        return change_s
    slope, icpt = np.polyfit(t, lag, 1)
    cross = -icpt / slope if slope != 0 else change_s
    return float(np.clip(cross, change_s, max(change_s, hi)))


def sensor_cause(
    alarm: Alarm, lost: np.ndarray, run: np.ndarray, rate_hz: float | None = None
) -> Cause:
    """The cause a sensor rule names: the channel, from its block's ``lost`` and ``run``;
    with ``rate_hz`` a stuck run is given in seconds, the unit the fault is injected with."""
    rule, channel = alarm.test.split("_", 1)
    kind = "dropout" if rule == "lost" else "stuck"
    j = CHANNELS.index(channel)
    if kind == "dropout":  # (a record's samples size it further: diagnosis.sensors)
        sev = float(lost[j])
        parameter = "fraction of the channel's samples lost (in the alarm block)"
    else:
        sev = float(run[j])
        parameter = "identical consecutive values (samples, in the alarm block)"
        if rate_hz is not None:  # at least: the run may have begun before the block
            sev /= rate_hz
            parameter = "time the channel repeats one value (s, at least: in the alarm block)"
    return Cause(channel, kind, "sensor", sev, (sev, sev), parameter, 0.0, 1.0, ())
