"""What the data can tell: sensitivity, collinearity, combinations, honest standard errors.

* **Sensitivity**: the norm of a parameter's Jacobian column, in units of the measurement
  noise; below :data:`MIN_SENSITIVITY` the data do not see the parameter at all.
* **Combinations**: parameters whose columns are (nearly) parallel act on the data as one
  (for mean roller speeds: every friction load only through the total torque at the motor);
  they are fitted as one factor and reported as "only in combination".
* **Collinearity index** (Brun, Reichert, Künsch 2001): gamma = 1 / sqrt(lambda_min) of the
  unit-norm columns' cross-product, reported; above :data:`MAX_COLLINEARITY` the set is
  numerically rank-deficient. Below it the standard errors, which carry the collinearity and
  the amount of data both, decide what is identified.
* **Absorbed members**: in a combination, a member whose effect is under
  :data:`ABSORB_RATIO` of the strongest member's cannot be told from it, and a plausible error
  in it moves the strongest one's estimate by that share at most: it stays nominal.
* **Standard errors** of the least-squares estimate by the sandwich formula with an
  autoregressive model of the residuals per record and channel: fluctuations the physics
  leaves out (drafting force, supply wander) make residuals coloured, and white-noise errors
  would then be too small by the square root of the correlation length.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from scipy.linalg import solve_toeplitz
from scipy.signal import lfilter

MIN_SENSITIVITY = 3.0
"""A parameter whose whole effect on the fit (column norm, in noise units) is below this is
not seen by the data."""
COMBINED_COSINE = 0.995
"""Columns this parallel (|cos|) are one combination for the data."""
MAX_COLLINEARITY = 1000.0
"""Collinearity index above which the free set is numerically rank-deficient: its weakest
direction is then below the finite-difference Jacobian's resolution (relative step 1e-3,
``fit.DIFF_STEP``). Below it, precision decides (:data:`MAX_RELATIVE_SE`, from honest
standard errors), not the index: the index measures the design, not the amount of data, and
grows as steady running is added to a start-up (steady levels see slip, belt and load through
two numbers). An earlier limit of 30 (Brun et al. call about 20 the limit) held on 60 s
records (index 18-27 for slip, belt and load on plant machine seeds 7-13) but on 180 s
records (index 36-40) sent the load back to nominal with relative errors of 8 % at most,
and the slip then came out 12 standard errors off (machine seed 7): more data, a worse and
overconfident calibration. At limits of 10 or 25 the same happened on 60 s records."""
MAX_RELATIVE_SE = 0.10
"""An estimate with a larger relative standard error is not identified."""
AR_ORDER = 10
ABSORB_RATIO = 0.1
"""A combination's member whose column norm is under this share of the strongest member's is
absorbed by it (left nominal)."""


def least_determined(relative_se: np.ndarray, gamma: float) -> int | None:
    """The free entry to send back to nominal (the one with the largest relative standard
    error), or None when the set is identified: every relative standard error within
    :data:`MAX_RELATIVE_SE` and the set not numerically rank-deficient."""
    if len(relative_se) == 0:
        return None
    if relative_se.max() <= MAX_RELATIVE_SE and gamma <= MAX_COLLINEARITY:
        return None
    return int(np.argmax(relative_se))


def sensitivities(jac: np.ndarray) -> np.ndarray:
    norms: np.ndarray = np.linalg.norm(jac, axis=0)
    return norms


def combine(jac: np.ndarray, candidates: Sequence[int]) -> list[list[int]]:
    """Groups of candidate columns that are nearly parallel (single-linkage on |cos|)."""
    cols = jac[:, candidates]
    unit = cols / np.maximum(np.linalg.norm(cols, axis=0), 1e-300)
    cos = np.abs(unit.T @ unit)
    parent = list(range(len(candidates)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i in range(len(candidates)):
        for j in range(i + 1, len(candidates)):
            if cos[i, j] > COMBINED_COSINE:
                parent[root(j)] = root(i)
    groups: dict[int, list[int]] = {}
    for i, c in enumerate(candidates):
        groups.setdefault(root(i), []).append(c)
    return list(groups.values())


def absorbed(jac: np.ndarray, group: Sequence[int]) -> tuple[list[int], list[int]]:
    """Split a combination into the members that carry it and those it absorbs (column norm
    under :data:`ABSORB_RATIO` of the strongest member's)."""
    norms = np.linalg.norm(jac[:, list(group)], axis=0)
    strong = norms >= ABSORB_RATIO * norms.max()
    return ([g for g, k in zip(group, strong, strict=True) if k],
            [g for g, k in zip(group, strong, strict=True) if not k])  # fmt: skip


def collinearity(jac: np.ndarray) -> float:
    """Brun's collinearity index of the columns (inf for a zero or dependent column)."""
    if jac.shape[1] < 2:
        return 1.0
    norms = np.linalg.norm(jac, axis=0)
    if (norms == 0).any():
        return float("inf")
    s = np.linalg.svd(jac / norms, compute_uv=False)
    return float(1.0 / s[-1]) if s[-1] > 0 else float("inf")


def standard_errors(jac: np.ndarray, residuals: np.ndarray) -> np.ndarray:
    """sqrt(diag(s^2 (J^T J)^-1)) by SVD, s^2 = SSR / (N - p)."""
    n, p = jac.shape
    if p == 0:
        return np.zeros(0)
    u, s, vt = np.linalg.svd(jac, full_matrices=False)
    dof = max(n - p, 1)
    s2 = float(residuals @ residuals) / dof
    inv = np.where(s > s[0] * 1e-12, 1.0 / np.maximum(s, 1e-300), np.inf)
    se: np.ndarray = np.sqrt(s2 * np.sum((vt.T * inv) ** 2, axis=1))
    return se


def sandwich_standard_errors(
    jac: np.ndarray,
    residuals: np.ndarray,
    mask: np.ndarray,
    record_rows: Sequence[tuple[int, int]],
    order: int = AR_ORDER,
) -> np.ndarray:
    """Standard errors of an ordinary least-squares estimate under coloured residuals:
    ``(J'J)^-1 J' S J (J'J)^-1`` with ``S`` the covariance of an AR(p) model fitted (Yule-Walker)
    to the residuals of each channel, each record a series of its own.

    ``jac`` and ``residuals`` hold the rows of the finite entries of a ``(blocks, channels)``
    array, row-major, as ``mask`` marks them. With ``r = A^-1 e`` (``A`` the AR filter, ``e``
    white with variance ``s2``), ``J' S J = s2 |A^-T J|^2``; ``A^-T`` is the AR synthesis filter
    run backwards in time."""
    n, p = jac.shape
    if p == 0:
        return np.zeros(0)
    resid = np.zeros(mask.shape)
    resid[mask] = residuals
    cols = np.zeros((*mask.shape, p))
    cols[mask] = jac
    meat = np.zeros((p, p))
    for j in range(mask.shape[1]):
        a = _yule_walker([resid[lo:hi, j] for lo, hi in record_rows], order)
        den = np.r_[1.0, -a]
        white = [lfilter(den, [1.0], resid[lo:hi, j])[mask[lo:hi, j]] for lo, hi in record_rows]
        e = np.concatenate(white)
        s2 = float(e @ e) / max(len(e) - p, 1)
        for lo, hi in record_rows:
            g = lfilter([1.0], den, cols[lo:hi, j][::-1], axis=0)[::-1]
            meat += s2 * (g.T @ g)
    bread = np.linalg.pinv(jac.T @ jac)
    cov = bread @ meat @ bread
    return np.sqrt(np.maximum(np.diag(cov), 0.0))


def hc3_standard_errors(jac: np.ndarray, residuals: np.ndarray) -> np.ndarray:
    """Heteroscedasticity-consistent standard errors with the leverage correction HC3
    (MacKinnon and White 1985): ``(J'J)^-1 J' diag(r_i^2 / (1 - h_i)^2) J (J'J)^-1``, ``h`` the
    hat matrix's diagonal. For residuals that are white only on average: where a few rows
    carry most of the information (a start-up's ramp after whitening) their own scatter,
    not the average one, sets the error, and HC3 undoes the shrinking of high-leverage rows'
    residuals by the fit itself."""
    n, p = jac.shape
    if p == 0:
        return np.zeros(0)
    bread = np.linalg.pinv(jac.T @ jac)
    leverage = np.einsum("ij,jk,ik->i", jac, bread, jac)
    weight = (residuals / np.maximum(1.0 - leverage, 1e-6)) ** 2
    cov = bread @ (jac.T * weight) @ jac @ bread
    return np.sqrt(np.maximum(np.diag(cov), 0.0))


def ar_whitener(
    residual_blocks: np.ndarray, record_rows: Sequence[tuple[int, int]], order: int = AR_ORDER
) -> Callable[[np.ndarray], np.ndarray]:
    """A function that whitens a ``(blocks, channels)`` residual array with the AR(p) model
    fitted (Yule-Walker) to ``residual_blocks`` per channel over all records; each record is
    filtered on its own. NaN blocks are treated as zero residuals (they are not scored)."""
    coeffs = []
    for j in range(residual_blocks.shape[1]):
        segments = [residual_blocks[a:b, j] for a, b in record_rows]
        coeffs.append(_yule_walker(segments, order))

    def whiten(r: np.ndarray) -> np.ndarray:
        out = np.empty_like(r)
        for j, a_coef in enumerate(coeffs):
            for a, b in record_rows:
                x = np.nan_to_num(r[a:b, j])
                out[a:b, j] = lfilter(np.r_[1.0, -a_coef], [1.0], x)
        return np.where(np.isfinite(r), out, np.nan)

    return whiten


def _yule_walker(segments: Sequence[np.ndarray], order: int) -> np.ndarray:
    """AR coefficients ``a`` (x_t = sum a_i x_{t-i} + e_t) from the pooled autocovariances."""
    xs = [np.nan_to_num(s - np.nanmean(s)) for s in segments if len(s) > order + 2]
    if not xs:
        return np.zeros(0)
    p = min(order, min(len(x) for x in xs) // 4)
    if p < 1:
        return np.zeros(0)
    acov = np.zeros(p + 1)
    total = sum(len(x) for x in xs)
    for x in xs:
        for k in range(p + 1):
            acov[k] += float(x[k:] @ x[: len(x) - k])
    acov /= total
    if acov[0] <= 0:
        return np.zeros(0)
    coef = solve_toeplitz(acov[:p], acov[1 : p + 1])
    return np.asarray(coef) if np.all(np.isfinite(coef)) else np.zeros(0)
