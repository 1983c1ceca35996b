"""The angle lags' random walk: measured on healthy records, and what it adds to the noise
of a shift measured against the detector's baseline.

A lag is a running sum of counted speeds; every lost row (or data-path spike) loses its
counts and the gap is re-anchored (:func:`drafttwin.diagnosis.residuals.angle_lag`), which
leaves an error of a fraction of an encoder edge each time (0.34 mrad SD on the third
roller, measured). Gaps come about once a second, so the counted lag random-walks against
the true one: 1-4 mrad a minute on the plant. An AR(1) model of the block lags does not hold
such a walk, and a shift measured over a window well after the baseline was formed carries
all the walk in between, so a severity interval sized with the AR(1) covariance alone was
too narrow (a 1.1 % chain elongation sized 1.054 [1.032, 1.076] % with one lost row before
its step).

:func:`lag_walk` measures the walk's rate on healthy records as the slope of the lags'
variogram at long separations; :func:`walk_covariance` gives the covariance it adds to the
means of the window's parts against an EWMA baseline (as :class:`~.detect.OnlineDetector`
forms it: the mean of a reference window, then tracked with weight ``alpha`` per block).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

SEPARATIONS = (10, 120)
"""Block separations whose variogram slope is the walk's rate (shorter ones still hold the
AR(1) part's rise; a record must be at least twice the shortest long to count)."""


def lag_walk(lags: Sequence[np.ndarray]) -> np.ndarray:
    """The lags' random-walk rate, ``(k, k)`` (mrad² per block), from healthy block lags
    ``(blocks, k)`` of one or more records: the least-squares slope of
    ``E[(x[t + tau] - x[t]) (x[t + tau] - x[t])^T]`` over ``tau`` in :data:`SEPARATIONS`,
    pooled over the records, made positive semi-definite. Zeros when no record is long
    enough (the detector then does not watch the lags, and the ranking does not judge them)."""
    k = lags[0].shape[1] if lags else 0
    lo, hi = SEPARATIONS
    taus, gammas = [], []
    for tau in range(lo, hi + 1):
        parts = [x[tau:] - x[:-tau] for x in lags if len(x) > max(tau, 2 * lo)]
        d = np.vstack(parts) if parts else np.zeros((0, k))
        d = d[np.isfinite(d).all(axis=1)]
        if len(d) < 10:
            break
        taus.append(tau)
        gammas.append(d.T @ d / len(d))
    if len(taus) < 3:
        return np.zeros((k, k))
    t = np.asarray(taus, dtype=np.float64)
    g = np.stack(gammas)  # (taus, k, k)
    tc = t - t.mean()
    slope = np.tensordot(tc, g - g.mean(axis=0), axes=(0, 0)) / float(tc @ tc)
    slope = 0.5 * (slope + slope.T)
    w, v = np.linalg.eigh(slope)
    psd: np.ndarray = (v * np.maximum(w, 0.0)) @ v.T
    return psd


def baseline_weights(end: int, n_ref: int, alpha: float) -> np.ndarray:
    """Weights of blocks ``0 .. end-1`` in the detector's baseline at block ``end``: the mean
    of the first ``n_ref`` blocks, then an EWMA with weight ``alpha`` per block (assuming it
    tracked every block; it pauses while a stream looks suspicious, which this ignores)."""
    end = max(int(end), 1)
    n_ref = max(1, min(int(n_ref), end))
    updates = end - n_ref
    w = np.zeros(end)
    w[:n_ref] = (1.0 - alpha) ** updates / n_ref
    if updates > 0:
        w[n_ref:] = alpha * (1.0 - alpha) ** np.arange(updates - 1, -1, -1)
    weights: np.ndarray = w / w.sum()
    return weights


def walk_covariance(parts: Sequence[np.ndarray], base: np.ndarray) -> np.ndarray:
    """Covariance, per unit walk rate, of each part's mean (block indices ``parts``) minus
    the baseline (``base``: weights of blocks ``0 .. len(base)-1``), ``(parts, parts)``: for
    a walk, ``cov(W[i], W[j])`` grows with ``min(i, j)``; the origin cancels because every
    mean's weights sum to one. ``min(i, j)`` is the number of steps ``k = 1 .. min(i, j)``,
    so each term is a sum over ``k`` of two tail sums of weights: linear in the record's
    length (a live twin's block index grows by 86 400 a day)."""
    idx = [np.asarray(p, dtype=np.int64) for p in parts]
    size = max([len(base), *(int(i.max()) + 1 for i in idx if len(i))])

    def tail(rows: np.ndarray, weights: np.ndarray) -> np.ndarray:
        dense = np.bincount(rows, weights=weights, minlength=size)
        sums: np.ndarray = np.cumsum(dense[::-1])[::-1][1:]  # weights at rows >= k, k >= 1
        return sums

    baseline = tail(np.arange(len(base)), base)
    tails = [tail(i, np.full(len(i), 1.0 / len(i))) - baseline for i in idx]
    out = np.array([[float(ta @ tb) for tb in tails] for ta in tails])
    cov: np.ndarray = 0.5 * (out + out.T)
    return cov
