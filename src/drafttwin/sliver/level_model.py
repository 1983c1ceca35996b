"""A levelling record prepared for :func:`drafttwin.sliver.action_point.find_action_point`,
and the regulating drive's lag and the material's delay that explain it.

The delivered log-mass is ``Y = Z + K * log f``: ``Z`` what the machine would deliver without
a leveller, ``K * log f`` the current correction through the drive (:class:`LevelModel`). The
drive's time constant ``tau`` is the one whose ``Z(tau) = Y - K * log f(tau)`` is best
explained by one delayed copy of the infeed reading (:func:`drive_and_delay`). The two sides
are smoothed crosswise first: ``Z`` by the reading's own smoothing (the fibres' lengths behind
the scanned place, the scanning rollers' contact length), the reading by the delivered
sliver's (``K``), so the material appears on both sides through the same two kernels. Without
that the delivered sliver is sharper than the reading (the reading averages the fed sliver
over its contact length and the fibres' lengths, the delivered sliver over the fibres'
lengths in delivered mm only, a draft's share), and a lag fitted there reads that sharpness
as the drive's; where the setting is right the correction lies on the material's own delay
and nothing else tells them apart: a 5-ms drive read 13-32 ms there and was called sluggish
on every healthy machine (docs/sliver.md). A block bootstrap gives the time constant's 95 %
interval, and the machine's nominal stands where that interval holds it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.signal import lfilter

from drafttwin.errors import DataError
from drafttwin.sliver.leveller import MAX_FACTOR, MIN_FACTOR, InfeedSensor, mass_kernel
from drafttwin.sliver.leveller_record import LevellerRecord, LevellerSetting
from drafttwin.sliver.sensor import SliverSensor
from drafttwin.sliver.staple import StapleDiagram

DRIVE_GRID_S = (0.0, 0.001, 0.0015, 0.002, 0.003, 0.004, 0.005, 0.0065, 0.008, 0.01, 0.013,
                0.016, 0.02, 0.025, 0.032, 0.04, 0.05, 0.063, 0.08, 0.1, 0.13, 0.16, 0.2, 0.25,
                0.3)  # fmt: skip
"""Time constants of the regulating drive tried, s."""
BLOCK_M = 5.0
"""Block length of the bootstraps (delivered sliver), m; shorter where the record has fewer
than :data:`MIN_BLOCKS` of them."""
MIN_BLOCKS = 8
"""Blocks the bootstraps want at least."""
DRIVE_RESAMPLES = 200
"""Resamples of the drive's bootstrap."""
SCAN_CONTACT_MM = InfeedSensor().averaging_mm
"""The scanning rollers' contact length the reading averages over, mm of fed sliver."""


@dataclass(frozen=True)
class LevelModel:
    """The record prepared once: rows of the analysis window and the smoothing kernel."""

    clock_mm: np.ndarray  # the store's clock of every row, mm
    reading: np.ndarray  # infeed reading relative to the reference, every row
    log_y: np.ndarray  # delivered log-mass (mean removed), every row
    kernel: np.ndarray  # fibres and delivery sensor, on the row grid
    dt_s: float
    start: int  # first row of the analysis window
    log_mean: float  # the mean log-mass removed from log_y
    step_m: float  # delivered sliver per row, m

    def held(self, delay_mm: float) -> np.ndarray:
        """The infeed reading the store holds ``delay_mm`` of fed sliver later, every row."""
        at = np.searchsorted(self.clock_mm, self.clock_mm - delay_mm, side="right") - 1
        return np.asarray(self.reading[np.clip(at, 0, None)])

    def lagged(self, values: np.ndarray, tau_s: float) -> np.ndarray:
        """``values`` (every row) through the regulating drive's first-order lag."""
        if tau_s <= 0:
            return values
        a = -math.expm1(-self.dt_s / tau_s)
        return np.asarray(lfilter([a], [1.0, a - 1.0], values, zi=[(1.0 - a) * values[0]])[0])

    def delivered(self, values: np.ndarray) -> np.ndarray:
        """``values`` (every row) through the delivered sliver's smoothing ``K``, every row."""
        return np.asarray(lfilter(self.kernel, [1.0], values))

    def log_factor(self, action_mm: float, intensity: float, tau_s: float) -> np.ndarray:
        """``log f`` of a setting at every row (the drive's lag included)."""
        x = self.held(action_mm)
        cmd = np.clip(1.0 / np.maximum(1.0 + intensity * (x - 1.0), 1e-9), MIN_FACTOR, MAX_FACTOR)
        return np.asarray(np.log(self.lagged(cmd, tau_s)))

    def effect(self, action_mm: float, intensity: float, tau_s: float) -> np.ndarray:
        """The setting's effect on the delivered log-mass, analysis window."""
        return self.delivered(self.log_factor(action_mm, intensity, tau_s))[self.start :]

    def linear(self, action_mm: float, tau_s: float) -> np.ndarray:
        """The effect of unit intensity to first order, analysis window: ``K * h_tau *
        (x(c - A) - 1)`` (``log f`` is about ``-I (x - 1)``)."""
        return self.delivered(self.lagged(self.held(action_mm) - 1.0, tau_s))[self.start :]

    def material_regressor(self, delay_mm: float) -> np.ndarray:
        """``K * log x(c - delay)``: the infeed reading at a delay through the delivered
        sliver's smoothing (the fibres' lengths and the delivery sensor), analysis window."""
        return self.delivered(np.log(self.held(delay_mm)))[self.start :]

    def as_read(self, values: np.ndarray, staple: StapleDiagram) -> np.ndarray:
        """``values`` (every row) through the infeed reading's own smoothing along the fed
        clock (the fibres' lengths behind each scanned place, then the scanning rollers'
        contact length), analysis window."""
        rows_per_mm = self.rows_per_fed_mm()
        fibres = mass_kernel(staple, 1.0 / rows_per_mm)
        out = np.convolve(values, fibres)[: values.size]
        width = max(1, int(round(SCAN_CONTACT_MM * rows_per_mm)))
        return np.asarray(uniform_filter1d(out, width, mode="nearest")[self.start :])

    def rows_per_fed_mm(self) -> float:
        """Rows per mm of fed sliver over the analysis window."""
        c = self.clock_mm[self.start :]
        return float((c.size - 1) / max(c[-1] - c[0], 1e-9))


def _kernel(staple: StapleDiagram, sensor: SliverSensor, step_mm: float) -> np.ndarray:
    """The fibres' smoothing of a change of end density, then the delivery sensor's boxcar
    and lag, on the row grid (sum 1)."""
    k = mass_kernel(staple, step_mm)
    width = max(1, int(round(sensor.averaging_mm / step_mm)))
    k = np.convolve(k, np.ones(width) / width)
    if sensor.lag_mm > 0:
        a = math.exp(-step_mm / sensor.lag_mm)
        lag = (1 - a) * a ** np.arange(int(8 * sensor.lag_mm / step_mm) + 1)
        k = np.convolve(k, lag / lag.sum())
    return np.asarray(k / k.sum())


def prepare(record: LevellerRecord, setting: LevellerSetting, staple: StapleDiagram,
            sensor: SliverSensor, reach_mm: float) -> LevelModel:  # fmt: skip
    """The record checked and prepared, its analysis window starting where the readings of
    every setting within ``reach_mm`` exist and the filters have settled."""
    clock = record.fed_length_m * 1e3
    if np.any(np.diff(clock) < 0) or not np.all(np.isfinite(clock)):
        raise DataError("fed_length_m is not a non-decreasing length clock",
                        source=record.source or None, where="--data, column fed_length_m",
                        fix="give the feeding rollers' travel at each reading")  # fmt: skip
    ref = setting.reference_ktex or float(np.median(record.infeed_ktex))
    reading = record.infeed_ktex / ref
    if not (np.all(np.isfinite(reading)) and np.all(reading > 0)
            and np.all(np.isfinite(record.delivery_ktex)) and np.all(record.delivery_ktex > 0)):  # fmt: skip
        raise DataError("infeed or delivery readings not finite numbers > 0",
                        source=record.source or None,
                        where="--data, columns infeed_ktex / linear_density_ktex",
                        fix="a leveller record has no gaps; cut it at the gap")  # fmt: skip
    y = np.log(record.delivery_ktex)
    step_mm = record.step_m * 1e3
    kernel = _kernel(staple, sensor, step_mm)
    dt = float(np.median(np.diff(record.time_s)))
    # rows whose readings at every searched setting exist, and the filters settled
    first = int(np.searchsorted(clock, clock[0] + reach_mm))
    settle = kernel.size + int(5 * max(DRIVE_GRID_S) / max(dt, 1e-9))
    start = first + settle
    if record.delivered_length_m.size - start < 1000:
        raise DataError(f"only {record.length_m:.3g} m of sliver: the store's reach "
                        f"({reach_mm:.0f} mm of fed sliver) leaves too little",
                        source=record.source or None, where="--data",
                        fix="give a record of a few hundred metres")  # fmt: skip
    mean = float(y[start:].mean())
    return LevelModel(clock, reading, y - mean, kernel, dt, start, mean, record.step_m)


def block_rows(n: int, step_m: float) -> int:
    """Rows per bootstrap block: 5 m, or an eighth of the analysed record where shorter."""
    return max(int(min(BLOCK_M, n * step_m / MIN_BLOCKS) / step_m), 1)


@dataclass(frozen=True)
class DriveFit:
    """The drive and the material's delay that explain a record.

    Attributes:
        time_constant_s: the drive's time constant, s: the nominal where the interval
            holds it, else the estimate.
        interval_s: the estimate's 95 % interval (block bootstrap), s.
        material_action_point_mm: where the fed material's mass reaches the delivery, mm of
            fed sliver from the scanning rollers (the setting of a drive without lag: the
            leading ends' transit less half the mass-mean fibre length, as the true action
            point is defined).
        transit_mm: the fibres' leading ends' transit from the scanning rollers to the
            delivery, mm of fed sliver (the delay that explains the record).
    """

    time_constant_s: float
    interval_s: tuple[float, float]
    material_action_point_mm: float
    transit_mm: float


def drive_and_delay(model: LevelModel, setting: LevellerSetting, grid: np.ndarray,
                    staple: StapleDiagram, seed: int = 0) -> DriveFit:  # fmt: skip
    """The drive's time constant and the material's delay that explain the record best: the
    least residual of ``Z(tau)`` on one delayed copy of the infeed reading, smoothed
    crosswise (see the module's docstring). The setting's nominal time constant stands where
    the estimate's 95 % interval holds it (a record without a leveller keeps it too); the
    interval is the estimate's either way. ``grid``: the action points searched, whose every
    other one is a delay tried."""
    nominal = setting.drive_time_constant_s
    levelled = setting.intensity > 0
    taus = sorted({*DRIVE_GRID_S, nominal}) if levelled else [nominal]

    def material(tau_s: float) -> np.ndarray:
        """``Z(tau)`` every row, through the reading's smoothing."""
        if not levelled:
            return model.as_read(model.log_y, staple)
        log_f = model.log_factor(setting.action_point_mm, setting.intensity, tau_s)
        return model.as_read(model.log_y - model.delivered(log_f), staple)

    zs = np.stack([material(t) for t in taus])
    zs -= zs.mean(axis=1, keepdims=True)
    rows = block_rows(zs.shape[1], model.step_m)
    n_blocks = max(zs.shape[1] // rows, 1)
    cut = n_blocks * min(rows, zs.shape[1])
    zb = zs[:, :cut].reshape(len(taus), n_blocks, -1)
    zz = np.einsum("tbr,tbr->tb", zb, zb)
    delays = grid[::2]
    zm = np.empty((len(taus), delays.size, n_blocks))
    mm = np.empty((delays.size, n_blocks))
    for j, delay in enumerate(delays):
        m = model.material_regressor(float(delay))
        mb = (m - m.mean())[:cut].reshape(n_blocks, -1)
        zm[:, j] = np.einsum("tbr,br->tb", zb, mb)
        mm[j] = np.einsum("br,br->b", mb, mb)

    def residuals(weights: np.ndarray) -> np.ndarray:
        m2 = mm @ weights
        return np.asarray((zz @ weights)[:, None] - (zm @ weights) ** 2
                          / np.where(m2 > 0, m2, np.inf))  # fmt: skip

    def pick(weights: np.ndarray) -> int:
        return int(np.unravel_index(int(np.argmin(residuals(weights))), zm.shape[:2])[0])

    whole = residuals(np.ones(n_blocks))
    best = pick(np.ones(n_blocks))
    interval = (float(taus[best]), float(taus[best]))
    if levelled and n_blocks > 1:
        rng = np.random.default_rng([seed, 1])
        counts = rng.multinomial(n_blocks, np.full(n_blocks, 1 / n_blocks), DRIVE_RESAMPLES)
        lo, hi = np.percentile([taus[pick(c.astype(float))] for c in counts], [2.5, 97.5])
        interval = (float(min(lo, taus[best])), float(max(hi, taus[best])))
        # the machine's own nominal stands unless the record rules it out
        if interval[0] <= setting.drive_time_constant_s <= interval[1]:
            best = taus.index(setting.drive_time_constant_s)
    delay = float(delays[int(np.argmin(whole[best]))])
    return DriveFit(float(taus[best]), interval, delay - staple.mass_mean_length_mm / 2, delay)


__all__ = ["BLOCK_M", "DRIVE_GRID_S", "MIN_BLOCKS", "DriveFit", "LevelModel",
           "block_rows", "drive_and_delay", "prepare"]  # fmt: skip
