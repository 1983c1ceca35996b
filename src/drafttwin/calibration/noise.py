"""A coloured model of the fit's residual: white noise plus an exponentially correlated part.

What the physics leaves out of a channel's block means is not white. On the motor channel the
VFD's output frequency wanders (an Ornstein-Uhlenbeck process, a few seconds of correlation)
and the motor follows it; nothing recorded measures it, and over one start-up ramp it looks
like a steeper or flatter motor curve. Fitted by plain least squares, such a wander is taken
for a parameter, and the white-noise standard errors are far too small.

Here each channel's residual (per record, on the block grid) is modelled as

    r(t) = u(t) + w(t),   cov(u(t), u(t')) = s_ou exp(-|t - t'| / tau),   var(w) = s_white

with ``s_ou``, ``tau`` and ``s_white`` estimated by maximum likelihood (Gaussian, the exact
covariance on the record's blocks, missing blocks left out), and the fit is weighted by the
inverse of that covariance (generalised least squares): each record's residual is replaced by
its standardised innovations (a Kalman filter, linear in the residual: the inverse Cholesky
factor of the covariance in time order, computed in O(n), gaps exact). Unlike an
autoregressive whitening filter fitted to the residual, which for a near-unit root (0.98 per
0.1 s block at 5 s correlation) is nearly a difference and keeps almost nothing of a steady
level, the exact covariance keeps what a level is worth: about one look per two correlation
times of the record, plus the white part's own.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.optimize import minimize

MIN_BLOCKS = 20
"""A record with fewer scored blocks in a channel says nothing about its correlation."""


@dataclass(frozen=True)
class ChannelNoise:
    """One channel's residual model (variances in the residual's units squared, tau in s)."""

    white_var: float
    ou_var: float
    tau_s: float

    def covariance(self, t_s: np.ndarray) -> np.ndarray:
        lag = np.abs(t_s[:, None] - t_s[None, :])
        ou = self.ou_var * np.exp(-lag / self.tau_s)
        cov: np.ndarray = ou + self.white_var * np.eye(len(t_s))
        return cov


@njit(cache=True)
def _innovations(
    t_s: np.ndarray, r: np.ndarray, white_var: float, ou_var: float, tau_s: float
) -> tuple[np.ndarray, float]:
    """Standardised innovations of ``r`` under the white + OU model (Kalman filter; a gap
    between blocks is an exact longer step) and the negative log-likelihood (without the
    constant). The innovations are ``L^-1 r`` for the Cholesky factor ``L`` of the
    covariance in time order: linear in ``r``, white with unit variance when the model holds."""
    z = np.empty(len(r))
    x, p, nll = 0.0, ou_var, 0.0
    for k in range(len(r)):
        if k > 0:
            a = np.exp(-(t_s[k] - t_s[k - 1]) / tau_s)
            x *= a
            p = a * a * p + ou_var * (1.0 - a * a)
        s = p + white_var
        v = r[k] - x
        z[k] = v / np.sqrt(s)
        nll += 0.5 * (np.log(s) + v * v / s)
        gain = p / s
        x += gain * v
        p *= 1.0 - gain
    return z, nll


def _neg_log_likelihood(
    theta: np.ndarray, segments: Sequence[tuple[np.ndarray, np.ndarray]]
) -> float:
    white_var, ou_var, tau_s = np.exp(theta)
    return float(sum(_innovations(t, r, white_var, ou_var, tau_s)[1] for t, r in segments))


def fit_noise(segments: Sequence[tuple[np.ndarray, np.ndarray]], block_s: float) -> ChannelNoise:
    """Maximum-likelihood white + OU model of residual segments ``(times_s, values)`` (each a
    record's scored blocks). The correlation time is bounded to [one block, the longest
    record]; either variance may vanish (down to 1e-6 of the total)."""
    usable = [(t, r) for t, r in segments if len(r) >= MIN_BLOCKS]
    if not usable:
        return ChannelNoise(1.0, 0.0, block_s)
    var = float(np.mean(np.concatenate([r for _, r in usable]) ** 2))
    var = max(var, 1e-300)
    longest = max(float(t[-1] - t[0]) for t, _ in usable)
    upper = max(longest, 2 * block_s)
    lo_v, hi_v = np.log(1e-6 * var), np.log(10 * var)
    bounds = [(lo_v, hi_v), (lo_v, hi_v), (np.log(block_s), np.log(upper))]
    best = None
    for share, tau in ((0.5, 10 * block_s), (0.8, 0.1 * upper)):  # two starts: short and long
        x0 = np.log([(1 - share) * var, share * var, min(max(tau, block_s), upper)])
        res = minimize(_neg_log_likelihood, x0, args=(usable,), method="L-BFGS-B", bounds=bounds)
        if best is None or res.fun < best.fun:
            best = res
    assert best is not None
    return ChannelNoise(*(float(v) for v in np.exp(best.x)))


def offset_sd(noise: ChannelNoise, times_s: Sequence[np.ndarray]) -> float:
    """Standard error of a constant offset shared by records (its generalised least-squares
    estimate) under ``noise``, on each record's scored block times: ``(sum 1' C_r^-1 1)^-1/2``,
    with ``1' C^-1 1 = |L^-1 1|^2`` by the same filter as the residual. For the motor channel
    this is how well the calibration records pin the steady level against the wander: the
    part of slip times load that no fit on these records can know better."""
    precision = sum(
        float(np.sum(_innovations(t, np.ones(len(t)), noise.white_var, noise.ou_var,
                                  noise.tau_s)[0] ** 2))
        for t in times_s if len(t)
    )  # fmt: skip
    return float(1.0 / np.sqrt(precision)) if precision > 0 else float("inf")


def mean_sd(noise: ChannelNoise, duration_s: float, block_s: float) -> float:
    """Standard deviation of the plain mean of a new record's residual over ``duration_s``:
    the wander's ``2 s^2 tau / T (1 - tau / T (1 - exp(-T / tau)))`` (an OU process's mean over
    ``T``) plus the white part over the record's blocks. A record's own wander moves its mean
    error by this much whatever the calibration (the wander's share of its bias)."""
    t, tau = float(duration_s), noise.tau_s
    if t <= 0:
        raise ValueError("a record mean needs a positive duration")
    ou = 2.0 * noise.ou_var * tau / t * (1.0 - tau / t * (1.0 - np.exp(-t / tau)))
    return float(np.sqrt(ou + noise.white_var / max(t / block_s, 1.0)))


class Whitener:
    """Replaces each (record, channel) residual by its standardised innovations under that
    channel's noise model (``L^-1 r``, ``L`` the Cholesky factor of its covariance on the
    scored blocks): white with unit variance when the model holds. Channels without a model
    are left as they are; blocks not scored (``mask`` false) are NaN."""

    def __init__(
        self,
        noises: Sequence[ChannelNoise | None],
        mask: np.ndarray,
        record_rows: Sequence[tuple[int, int]],
        block_s: float,
    ) -> None:
        self.mask = mask
        self.parts = [
            (j, lo + idx, idx * block_s, noise)
            for j, noise in enumerate(noises) if noise is not None
            for lo, hi in record_rows
            for idx in [np.flatnonzero(mask[lo:hi, j])] if len(idx)
        ]  # fmt: skip

    def __call__(self, r: np.ndarray) -> np.ndarray:
        out = np.where(self.mask, r, np.nan)
        for j, rows, t_s, n in self.parts:
            out[rows, j] = _innovations(t_s, np.ascontiguousarray(r[rows, j], dtype=np.float64),
                                        n.white_var, n.ou_var, n.tau_s)[0]  # fmt: skip
        return out


def channel_segments(
    residual: np.ndarray, mask: np.ndarray, record_rows: Sequence[tuple[int, int]], j: int,
    block_s: float,
) -> list[tuple[np.ndarray, np.ndarray]]:  # fmt: skip
    """Channel ``j``'s scored residual blocks, one ``(times_s, values)`` segment per record."""
    out = []
    for lo, hi in record_rows:
        idx = np.flatnonzero(mask[lo:hi, j])
        out.append((idx * block_s, residual[lo + idx, j]))
    return out
