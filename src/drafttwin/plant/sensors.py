"""The measurement chain: encoders counting pulses over each sample window, and the defects
of the data path (dropped samples, bursts of them, spikes), each recorded where it was put.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drafttwin.plant.config import Sensors


@dataclass(frozen=True)
class Measured:
    """Measured speeds (rpm, NaN = missing) and the record of what the data path did."""

    rpm: np.ndarray
    missing: np.ndarray  # bool (n, rollers): sample dropped
    outlier: np.ndarray  # bool (n, rollers): spike injected


def encoder_rpm(
    true_rpm: np.ndarray, window_s: float, cfg: Sensors, rng: np.random.Generator
) -> np.ndarray:
    """Speeds an incremental encoder reports by counting edges over each sample window.

    The true angle at each window boundary comes from the true interval-mean speeds; the
    boundary instants jitter by ``clock_jitter_s``; counts are whole edges
    (``pulses_per_rev * quadrature`` per revolution) and the speed is counts over the nominal
    window. Quantisation step: ``60 / (counts_per_rev * window_s)`` rpm.
    """
    counts_per_rev = cfg.pulses_per_rev * cfg.quadrature
    n, k = true_rpm.shape
    rev = np.vstack([np.zeros((1, k)), np.cumsum(true_rpm / 60.0 * window_s, axis=0)])
    rev += rng.uniform(0.0, 1.0, size=(1, k))  # arbitrary encoder zero
    boundary_rate = np.vstack([true_rpm[:1], true_rpm]) / 60.0
    rev += boundary_rate * cfg.clock_jitter_s * rng.standard_normal((n + 1, 1))
    counts = np.floor(rev * counts_per_rev)
    rpm: np.ndarray = np.diff(counts, axis=0) / counts_per_rev * 60.0 / window_s
    return rpm


def inject_defects(rpm: np.ndarray, rate_hz: float, cfg: Sensors, rng_missing: np.random.Generator,
                   rng_outlier: np.random.Generator) -> Measured:  # fmt: skip
    """Drop samples (whole logger rows: singles and bursts) and add spikes to single channels."""
    n, k = rpm.shape
    out = rpm.copy()
    single_rng, burst_rng = rng_missing.spawn(2)  # separate streams: shorter runs are a prefix
    # size as a shape tuple: the same draws as size=n, and typed as an array (n is untyped)
    row_dropped = single_rng.random((n,)) < cfg.missing_rate
    if cfg.burst_rate_per_min > 0:
        mean_gap = 60.0 * rate_hz / cfg.burst_rate_per_min  # samples between burst starts
        pos = 0.0
        lo, hi = cfg.burst_length
        while True:
            pos += burst_rng.exponential(mean_gap)
            length = int(burst_rng.integers(lo, hi + 1))
            start = int(pos)
            if start >= n:
                break
            row_dropped[start : start + length] = True
    u = rng_outlier.random((n, k, 3))  # per sample: spike?, size, sign (row-major: prefix-safe)
    spikes = u[..., 0] < cfg.outlier_rate
    lo_size, hi_size = cfg.outlier_size
    size = lo_size + (hi_size - lo_size) * u[..., 1]
    sign = np.where(u[..., 2] < 0.5, -1.0, 1.0)
    outlier = spikes & ~row_dropped[:, None]
    out[outlier] *= 1.0 + (sign * size)[outlier]
    missing = np.repeat(row_dropped[:, None], k, axis=1)
    out[missing] = np.nan
    return Measured(out, missing, outlier)


def quantisation_step_rpm(cfg: Sensors, rate_hz: float) -> float:
    """Speed resolution of pulse counting at a sample rate, rpm."""
    return 60.0 * rate_hz / (cfg.pulses_per_rev * cfg.quadrature)
