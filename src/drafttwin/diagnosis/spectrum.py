"""Spectral evidence at the frequencies the kinematics predict.

For every shaft (node) of the train, its rotation frequency at the record's speed, and the
tooth frequencies of meshes and chain folded to the record's Nyquist band: the amplitude of
each channel's relative residual there before the change (the reference) and after it, by
Hann-windowed spectra of equal windows; a line counts when it grew
:data:`GROWTH` times over its earlier amplitude and over the local noise floor. A line that grew names the elements turning at
that rate (a gear run-out shows at its gear's shaft rate; a roller run-out at the roller's).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.signal import medfilt

from drafttwin.data.series import MeasurementSeries
from drafttwin.diagnosis.blocks import ANGLE_SPIKE
from drafttwin.diagnosis.residuals import CHANNELS, measured
from drafttwin.mechanics import DriveTrain, kinematics

GROWTH = 3.0  # a line counts as implicated when it grew this much ...
FLOOR = 1e-4  # ... exceeds this relative amplitude (0.01 %) and the local noise floor
MIN_HZ = 2.0  # below, slow drafting-force and supply wander dominate
SPIKE_NEIGHBOURS = 5  # a reading is judged against the median of this many around it


@dataclass(frozen=True)
class LineEvidence:
    """A kinematic line that grew after the change."""

    name: str  # e.g. "shaft back_drive" or "mesh E-F (alias)"
    freq_hz: float
    channel: str
    before: float  # relative amplitude (fraction of the speed)
    after: float
    elements: tuple[str, ...]

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "freq_hz": self.freq_hz, "channel": self.channel,
                "before_percent": 100 * self.before, "after_percent": 100 * self.after,
                "elements": list(self.elements)}  # fmt: skip


def kinematic_lines(train: DriveTrain, motor_rpm: float, rate_hz: float) -> list[tuple[str, float, tuple[str, ...]]]:  # fmt: skip
    """(name, frequency folded into [0, rate/2], elements turning there) of every line."""
    kin = kinematics(train, motor_rpm=motor_rpm)
    spec = train.spec
    rollers_on = {r.node: r.name for r in spec.roller}
    out = []
    for node, rpm in kin.node_rpm.items():
        elements = [g.name for g in spec.gear if node in (g.driver, g.driven)]
        if node in rollers_on:
            elements.append(rollers_on[node])
        out.append((f"shaft {node}", _fold(rpm / 60.0, rate_hz), tuple(elements)))
    for name, f in {**kin.mesh_frequencies_hz, **kin.chain_tooth_frequencies_hz}.items():
        out.append((f"tooth {name}", _fold(f, rate_hz), (name,)))
    return out


def _fold(f: float, rate_hz: float) -> float:
    f = f % rate_hz
    return min(f, rate_hz - f)


def spectrum(x: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Frequencies and amplitude spectrum of ``x`` (NaN-free): linear trend removed (a step or
    a ramp would leak into every line), Hann window, amplitude-corrected."""
    t = np.arange(len(x)) / rate_hz
    x = x - np.polyval(np.polyfit(t, x, 1), t)
    w = np.hanning(len(x))
    return np.fft.rfftfreq(len(x), 1 / rate_hz), 2 * np.abs(np.fft.rfft(w * x)) / w.sum()


def line_and_floor(freqs: np.ndarray, amp: np.ndarray, f: float) -> tuple[float, float]:
    """Peak amplitude within two bins of ``f`` and the median of the bins within 1 Hz."""
    df = freqs[1] - freqs[0]
    near = np.abs(freqs - f) <= 2 * df
    local = (np.abs(freqs - f) <= 1.0) & ~near
    return float(amp[near].max()), float(np.median(amp[local])) if local.any() else 0.0


def residual_samples(series: MeasurementSeries) -> np.ndarray:
    """Per-sample relative deviation from each channel's median, gaps and data-path spikes
    (a reading :data:`~drafttwin.diagnosis.blocks.ANGLE_SPIKE` off the median of its five
    neighbours: a wrong reading, as the detection leaves it out) interpolated. One 27 % spike
    in a window had lifted its spectrum's floor tenfold over every line."""
    y = measured(series)
    out = np.empty_like(y)
    idx = np.arange(len(y))
    for j in range(y.shape[1]):
        col = y[:, j]
        ok = np.isfinite(col)
        if not ok.any():
            out[:, j] = 0.0
            continue
        dev = col[ok] / np.median(col[ok]) - 1.0
        keep = np.abs(dev - medfilt(dev, SPIKE_NEIGHBOURS)) <= ANGLE_SPIKE
        kept = idx[ok][keep]
        out[:, j] = np.interp(idx, kept, dev[keep]) if len(kept) else 0.0
    return out


def line_evidence(train: DriveTrain, series: MeasurementSeries, change_s: float,
                  alarm_s: float) -> list[LineEvidence]:  # fmt: skip
    """Lines that grew from before ``change_s`` to after ``alarm_s`` on any channel (equal
    window lengths), the largest growth first."""
    rate = series.sample_rate_hz
    y = measured(series)
    motor = float(np.nanmedian(y[:, 4])) if np.isfinite(y[:, 4]).any() else None
    if motor is None or not np.isfinite(motor) or motor <= 0:
        return []
    r = residual_samples(series)
    before, after = r[series.time_s <= change_s], r[series.time_s > alarm_s]
    n = min(len(before), len(after))
    if n < 4 * rate:
        return []
    before, after = before[-n:], after[:n]
    out = []
    spectra = [
        (spectrum(before[:, j], rate), spectrum(after[:, j], rate)) for j in range(len(CHANNELS))
    ]
    for name, f, elements in kinematic_lines(train, motor, rate):
        if f < MIN_HZ:
            continue
        for j, ch in enumerate(CHANNELS):
            a0, floor0 = line_and_floor(*spectra[j][0], f)
            a1, floor1 = line_and_floor(*spectra[j][1], f)
            if a1 > FLOOR and a1 > GROWTH * max(a0, floor0, floor1):
                out.append(LineEvidence(name, f, ch, a0, a1, elements))
    return sorted(out, key=lambda e: -(e.after / max(e.before, 1e-12)))[:10]
