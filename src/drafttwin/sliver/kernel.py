"""The fibre-level drafting kernel (numba): ideal drafting through three zones.

Each fibre is drawn (leading end, length, linear density), carried through the zones and
deposited on the delivered-length grid, one at a time, so memory does not grow with the
number of fibres (1e8 fibres per 100 m of a 5 ktex sliver).

Ideal drafting: a fibre moves with the slower roller until its leading end reaches the next
nip, then with that roller. On a common time grid every roller's cumulative surface length
``S_k`` is non-decreasing, so "the time the leading end reaches a nip" is a walk along that
grid; fed positions in order give walks that only move forward (:func:`transport_map`
tabulates them once; :func:`draft_random` interpolates in that table).

Arrays (lengths in mm): ``surface`` ``(m, 4)`` the cumulative surface lengths of front,
second, third, back on a uniform time grid; ``gauges`` ``(3,)`` main (front-second), middle
(second-third), break (third-back).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

FRONT, SECOND, THIRD, BACK = 0, 1, 2, 3
STATE = ("u", "k", "count", "pending", "done")
"""Slots of :func:`draft_random`'s ``state``: the unit Poisson process's position, the fed
grid interval, fibres drafted, a drawn leading end not yet used (1), the feed or the record
ended (1)."""


@njit(cache=True, inline="always", error_model="numpy")
def _walk(s: np.ndarray, col: int, j: int, target: float) -> tuple[int, float]:
    """First grid interval ``j`` (from ``j`` on) where column ``col`` reaches ``target``, and
    the fraction of the interval; ``j = -1`` if it never does within the grid."""
    m = s.shape[0]
    while j < m - 1 and s[j + 1, col] < target:
        j += 1
    if j >= m - 1:
        return -1, 0.0
    den = s[j + 1, col] - s[j, col]
    frac = (target - s[j, col]) / den if den > 0 else 0.0
    return j, min(max(frac, 0.0), 1.0)


@njit(cache=True, inline="always", error_model="numpy")
def _at(s: np.ndarray, col: int, j: int, frac: float) -> float:
    return s[j, col] + frac * (s[j + 1, col] - s[j, col])


@njit(cache=True, error_model="numpy")
def _deposit(diff: np.ndarray, a: float, length: float, w: float, h: float) -> None:
    """Add a fibre covering delivered ``[a, a + length]`` mm with weight ``w`` (tex) to the
    difference array of the bin averages (cloud in cell at both ends: exact bin means)."""
    _edge(diff, a / h, w)
    _edge(diff, (a + length) / h, -w)


@njit(cache=True, inline="always", error_model="numpy")
def _edge(diff: np.ndarray, x: float, w: float) -> None:
    """One end of a fibre at grid position ``x`` (bins), weight ``w`` (negative: trailing)."""
    if x <= 0.0:
        diff[0] += w
        return
    k = int(x)
    if k >= diff.shape[0] - 2:
        return
    f = x - k
    diff[k] += w * (1.0 - f)
    diff[k + 1] += w * f


@njit(cache=True, error_model="numpy")
def _transport(surface: np.ndarray, gauges: np.ndarray, p: float,
               ptr: np.ndarray) -> tuple[float, int]:  # fmt: skip
    """Delivered position (mm) of the leading end of a fibre whose leading end is at fed
    position ``p`` (the back roller's surface length when it passes the back nip), and the
    grid interval at which it reaches the front nip (-1: not within the grid). ``ptr``
    holds the three walks' positions and is advanced."""
    j, f = _walk(surface, BACK, ptr[0], p + gauges[2])
    ptr[0] = max(j, 0)
    if j < 0:
        return 0.0, -1
    j2, f2 = _walk(surface, THIRD, ptr[1], _at(surface, THIRD, j, f) + gauges[1])
    ptr[1] = max(j2, 0)
    if j2 < 0:
        return 0.0, -1
    j3, f3 = _walk(surface, SECOND, ptr[2], _at(surface, SECOND, j2, f2) + gauges[0])
    ptr[2] = max(j3, 0)
    if j3 < 0:
        return 0.0, -1
    return _at(surface, FRONT, j3, f3), j3


@njit(cache=True, error_model="numpy")
def transport_map(surface: np.ndarray, gauges: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Delivered leading-end position (mm) of a fibre fed at each sorted position ``p``
    (mm); NaN from the first that is not delivered within the grid."""
    out = np.full(p.shape[0], np.nan)
    ptr = np.zeros(3, dtype=np.int64)
    for i in range(p.shape[0]):
        s_lead, j = _transport(surface, gauges, p[i], ptr)
        if j < 0:
            break
        out[i] = s_lead
    return out


@njit(cache=True, error_model="numpy")
def draft_random(rng: np.random.Generator, lead: np.ndarray, quantiles: np.ndarray, cum: np.ndarray,
                 feed: np.ndarray, drift: np.ndarray, h: float, diff: np.ndarray,
                 keep: np.ndarray, state: np.ndarray) -> None:  # fmt: skip
    """Draw and draft the fibres of a random feed up to a fed position; deposit them.

    ``quantiles`` ``(2, q + 1)``: inverse CDFs of length (mm) and fibre linear density (tex);
    ``cum``: the feed's cumulative rate (expected fibres) on the fed-length grid, and
    ``lead`` the delivered position (mm) of a leading end fed at each grid point
    (:func:`transport_map`; NaN: not delivered within the record), interpolated linearly
    within a grid step (a step of 0.1 mm fed is 0.66 mm delivered at the FA320A's draft,
    finer than any speed grid the rollers are given on).
    ``feed = (p0, dp, fibre_scale, p_stop, real)``: the fed-length grid of ``cum`` starts at
    ``p0`` mm with step ``dp``; each drawn fibre stands for ``fibre_scale`` fibres (its weight
    is scaled, the number drawn divided); the call returns at the first leading end past
    ``p_stop``, and a later call with the same ``rng`` (NumPy's Generator, its state advanced
    in place) goes on from ``state`` (:data:`STATE`): pieces give the same sliver as one
    call. ``real``: draw each fibre's acceleration number (real drafting, both passes). ``drift`` is the
    real-drafting table (:func:`_early`; empty: ideal drafting). ``keep`` ``(r, 3)`` receives
    the first ``r`` fibres (delivered leading end mm, length mm, tex) for a later passage.
    Every fibre draws the same random numbers with or without real drafting, so both passes
    of the real-drafting model see one set of fibres.
    """
    q = quantiles.shape[1] - 1
    p0, dp, scale, p_stop, real = feed[0], feed[1], feed[2], feed[3], feed[4] > 0
    u, k, count = state[0], int(state[1]), int(state[2])
    s_end = (diff.shape[0] - 2) * h
    if drift.shape[0] > 0:  # fibres landing early may come from beyond the grid's end
        s_end += (drift[2] - 1.0) * drift[4]
    n_cum = cum.shape[0]
    while True:
        if state[3] > 0:
            state[3] = 0.0
        else:
            u += rng.exponential(scale)
        while k < n_cum - 1 and cum[k + 1] < u:
            k += 1
        if k >= n_cum - 1:
            state[4] = 1.0
            break
        den = cum[k + 1] - cum[k]
        frac = (u - cum[k]) / den if den > 0 else 0.0
        if p0 + dp * (k + frac) > p_stop:
            state[3] = 1.0
            break
        length = _quantile(quantiles[0], q, rng.random())
        tex = _quantile(quantiles[1], q, rng.random()) * scale
        u_x = rng.random() if real else 0.0
        s_lead = lead[k] + frac * (lead[k + 1] - lead[k])
        if not s_lead <= s_end:  # beyond the record, or not delivered within it (NaN)
            state[4] = 1.0
            break
        s_lead -= _early(drift, s_lead, length, h, u_x)
        if s_lead + length > 0.0:
            _deposit(diff, s_lead, length, tex, h)
        if count < keep.shape[0]:
            keep[count, 0], keep[count, 1], keep[count, 2] = s_lead, length, tex
        count += 1
    state[0], state[1], state[2] = u, float(k), float(count)


@njit(cache=True, inline="always", error_model="numpy")
def _quantile(table: np.ndarray, q: int, u: float) -> float:
    x = u * q
    i = min(int(x), q - 1)
    return table[i] + (x - i) * (table[i + 1] - table[i])


@njit(cache=True, error_model="numpy")
def _early(drift: np.ndarray, s_lead: float, length: float, h: float, u_x: float) -> float:
    """Real drafting: how much earlier (delivered mm) a floating fibre lands because it
    accelerates a distance X before the front nip: ``(D_main - 1) X``, with
    ``X = x_mean * 2U * (1 + beta * (c - 1))``, U uniform, ``c`` the ideal sliver's mean
    density over the fibre length ahead of its leading end relative to its mean (fibres
    already fast drag floating ones: correlated acceleration). 0 for ideal drafting."""
    if drift.shape[0] == 0:
        return 0.0
    x_mean, beta, d_main, rho_mean, gauge = drift[0], drift[1], drift[2], drift[3], drift[4]
    if length >= gauge:
        return 0.0  # held by a nip: not floating
    cum = drift[5:]
    n = cum.shape[0] - 1
    lo = min(max((s_lead - length) / h, 0.0), float(n))
    hi = min(max(s_lead / h, 0.0), float(n))
    c = 1.0
    if hi - lo > 0.5:
        c = (_interp_cum(cum, hi) - _interp_cum(cum, lo)) / ((hi - lo) * rho_mean)
    x = x_mean * 2.0 * u_x * (1.0 + beta * (c - 1.0))
    x = min(max(x, 0.0), gauge - length)
    return (d_main - 1.0) * x


@njit(cache=True, inline="always", error_model="numpy")
def _interp_cum(cum: np.ndarray, x: float) -> float:
    i = min(int(x), cum.shape[0] - 2)
    return cum[i] + (x - i) * (cum[i + 1] - cum[i])


@njit(cache=True, error_model="numpy")
def draft_given(lead: np.ndarray, lengths: np.ndarray, tex: np.ndarray, surface: np.ndarray,
                gauges: np.ndarray, h: float, diff: np.ndarray,
                out_lead: np.ndarray) -> int:  # fmt: skip
    """Draft given fibres (sorted by fed leading-end position ``lead``, mm): a later passage
    fed with an earlier one's fibres. Deposits into ``diff``, writes each fibre's delivered
    leading end to ``out_lead`` (NaN if not delivered within the grid); returns the number
    delivered."""
    ptr = np.zeros(3, dtype=np.int64)
    count = 0
    for i in range(lead.shape[0]):
        s_lead, j = _transport(surface, gauges, lead[i], ptr)
        if j < 0:
            for r in range(i, lead.shape[0]):
                out_lead[r] = np.nan
            break
        out_lead[i] = s_lead
        if s_lead + lengths[i] > 0.0:
            _deposit(diff, s_lead, lengths[i], tex[i], h)
        count += 1
    return count


@njit(cache=True, error_model="numpy")
def level_surface(surface: np.ndarray, readings: np.ndarray, setting: np.ndarray,
                  out: np.ndarray, factor: np.ndarray) -> None:  # fmt: skip
    """An open-loop leveller through the main draft, step by step along the time grid.

    ``surface`` ``(m, 4)``: the rollers' unlevelled surface lengths (mm); ``readings``: the
    infeed sensor's relative readings (1: the reference count) at fed positions ``q0 + k
    pitch``, each held until the next; ``setting = (q0, pitch, scan_minus_store, intensity,
    drive_a, lo, hi)``. At each step the store hands over the reading of the fed position
    ``S_back + scan_minus_store`` (clocked by the feeding rollers' own travel, as a levelling
    computer clocks its store), the command is ``1 / (1 + intensity (reading - 1))`` within
    ``[lo, hi]``, and the regulating drive follows it as a first-order lag (``drive_a = 1 -
    exp(-dt / tau)`` per step). Second, third and back roller (``out``) advance by their
    unlevelled travel times the drive's factor; the front roller keeps its own. ``factor``
    receives the drive's factor in each step. A run continued piece by piece
    (:mod:`drafttwin.sliver.stream`) gives the drive's factor so far as ``setting[7]`` and
    the levelled first row in ``out[0]``."""
    q0, pitch, ahead, intensity = setting[0], setting[1], setting[2], setting[3]
    a, lo, hi = setting[4], setting[5], setting[6]
    n_read = readings.shape[0]
    if setting.shape[0] > 7:
        f = setting[7]
    else:
        out[0, :] = surface[0, :]
        f = -1.0
    for i in range(surface.shape[0] - 1):
        k = int(math.floor((out[i, BACK] + ahead - q0) / pitch))
        x = readings[min(max(k, 0), n_read - 1)]
        cmd = 1.0 / max(1.0 + intensity * (x - 1.0), 1e-9)
        cmd = min(max(cmd, lo), hi)
        f = cmd if f < 0.0 else f + (cmd - f) * a  # the drive starts settled
        factor[i] = f
        out[i + 1, FRONT] = surface[i + 1, FRONT]
        for c in range(1, 4):
            out[i + 1, c] = out[i, c] + (surface[i + 1, c] - surface[i, c]) * f
    factor[surface.shape[0] - 1] = f
