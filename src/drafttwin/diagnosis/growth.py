"""Is the fault still growing? The trend of a cause's severity block by block.

The ranking sizes a cause by the mean shift over the window after the alarm: for a ramp
that is the severity somewhere in the window's middle, not what the machine has now. Here
each block's features (levels and angle lags minus the baseline at the alarm) are sized on
their own, by the cause's signature (Gauss-Newton with the healthy block covariance as the
weight; one step for the kinds the model is linear in), and a straight line through the last
:data:`~drafttwin.diagnosis.diagnose.POST_S` seconds of the record gives the rate and the
severity at the middle of the last block. Its standard errors are ordinary least squares,
inflated for the blocks' autocorrelation (the larger of the residuals' lag-1 correlation and
the detector's healthy one, AR(1): ``(1 + r) / (1 - r)``), so that the slow wander of an
angle lag does not pass for growth. The fault is growing when the rate's 99 % interval
excludes zero and it grows the way the severity points.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import t as student_t

from drafttwin.diagnosis.locate import ANGLE_KINDS, Cause, Growth, SignatureModel
from drafttwin.diagnosis.residuals import CHANNELS
from drafttwin.mechanics.faults import KINDS

MIN_BLOCKS = 6  # fewer blocks give no trend worth a word
GROWING_LEVEL = 0.99  # two-sided confidence that the rate is not zero
ITERATIONS = 4  # chord steps for the kinds whose signature bends with the severity


def block_severities(model: SignatureModel, cause: Cause, dev: np.ndarray,
                     block_cov: np.ndarray) -> np.ndarray:  # fmt: skip
    """The severity each block's features ``dev`` (rows: levels, then the lags) shows on its
    own for ``cause``, weighted by the healthy block covariance ``block_cov``. An encoder
    gain is sized by its level alone (its lag depends on how long it has run)."""
    nc = len(CHANNELS)
    used = nc if cause.kind == "gain" else dev.shape[1]
    d = dev[:, :used]
    weight = np.linalg.pinv(block_cov[:used, :used])
    lo, hi = (-KINDS[cause.kind].high, KINDS[cause.kind].high)
    lo = lo if KINDS[cause.kind].signed else 0.0

    def sig(s: float) -> np.ndarray:
        return model.signature(cause.element, cause.kind, s)[:used]

    ref = cause.severity if cause.severity != 0 else KINDS[cause.kind].levels[0]
    step = 1e-3 * max(abs(ref), KINDS[cause.kind].levels[0])
    g = (sig(ref + step) - sig(ref - step)) / (2 * step)
    gwg = float(g @ weight @ g)
    if gwg <= 0:
        return np.full(len(d), np.nan)
    linear = cause.kind in ANGLE_KINDS or cause.kind == "gain"
    s = np.full(len(d), ref)
    for _ in range(1 if linear else ITERATIONS):  # chord method: the slope at ref
        pred = np.array([sig(float(x)) for x in s])
        s = np.clip(s + ((d - pred) @ weight @ g) / gwg, lo, hi)
    return s


def severity_trend(severity: np.ndarray, mid_s: np.ndarray, phi_floor: float,
                   sign: float) -> Growth | None:  # fmt: skip
    """A line through the block severities at their mid times; ``phi_floor``: the healthy
    blocks' autocorrelation; ``sign``: the direction the severity grows in (+1, or -1 for
    a negative gain). None with fewer than :data:`MIN_BLOCKS` finite blocks."""
    ok = np.isfinite(severity)
    y, t = severity[ok], mid_s[ok]
    n = len(y)
    if n < MIN_BLOCKS or np.ptp(t) == 0:
        return None
    t_end = float(t[-1])
    x = t - t_end
    slope, at_end = np.polyfit(x, y, 1)
    e = y - (at_end + slope * x)
    r = float(e[1:] @ e[:-1] / (e @ e)) if e @ e > 0 else 0.0
    r = float(np.clip(max(r, phi_floor), 0.0, 0.95))
    var = float(e @ e) / (n - 2) * (1 + r) / (1 - r)
    sxx = float(((x - x.mean()) ** 2).sum())
    se_rate = math.sqrt(var / sxx)
    se_end = math.sqrt(var * (1 / n + x.mean() ** 2 / sxx))
    q95, q_grow = student_t.ppf(0.975, n - 2), student_t.ppf(0.5 + GROWING_LEVEL / 2, n - 2)
    growing = bool(sign * slope > 0 and se_rate > 0 and abs(slope) > q_grow * se_rate)
    return Growth(growing, float(slope), (float(slope - q95 * se_rate), float(slope + q95 * se_rate)),
                  float(at_end), (float(at_end - q95 * se_end), float(at_end + q95 * se_end)),
                  t_end, n)  # fmt: skip
