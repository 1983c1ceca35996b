"""The autoleveller's action point and intensity from running data (research/sliver.md 6).

A levelling drawframe records, for every delivery reading, the infeed scanning rollers'
reading and its store's length clock (the feeding rollers' travel). The leveller's current
correction follows from those readings and its setting: at each delivery reading it applied
``f = 1 / (1 + I (x(c - A) - 1))`` through its drive (``x``: the infeed reading relative to
the reference count, taken when the clock read ``c - A``; ``I`` the intensity, ``A`` the
action point setting), and a speed factor ``f`` of the feeding rollers changes the delivered
mass by ``f`` at once (second, third and back roller move together: the drafting transfer's
gains add up to 1 at every wavelength), spread over the fibres' lengths. So the delivered
log-mass ``Y`` is ``Z + K * log f``, where ``Z`` is what the machine would deliver without a
leveller and ``K`` the fibres' and the delivery sensor's smoothing. :func:`find_action_point`

1. takes the current correction out, ``Z = Y - K * log f(A_cur, I_cur, tau)``, with the
   drive's time constant ``tau`` chosen where ``Z`` is best explained by one delayed copy of
   the infeed reading (a wrong ``tau`` leaves a filtered copy of the reading at the current
   setting in ``Z``), both smoothed crosswise so that the material's path and the reading
   share their kernels, and the nominal kept where the record's interval holds it
   (:mod:`drafttwin.sliver.level_model`); that delay is the material's own
   (``estimated_action_point_mm``);
2. puts any other setting in, ``Y' = Z + K * log f(A, I, tau)``, and finds the ``(A, I)`` of
   the least variance: the brute-force tuning run of research/sliver.md 6, on one record;
3. gives the CV, CV(1 m), CV(3 m), CV(5 m) of ``Y'`` beside the recorded ones, a 95 %
   interval from a bootstrap over 5-m blocks, and the metres from which that interval is
   within +-5 mm.

What it cannot see: the feed must vary (its long and medium waves carry the information; a
feed without them gives a wide interval, which the result says), and the delivered mass of
another setting is extrapolated from this record's to first order (the fed material reaches
the delivery a few mm earlier or later).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy.signal import lfilter

from drafttwin.sliver.irregularity import evenness
from drafttwin.sliver.level_model import (
    DRIVE_GRID_S,
    MIN_BLOCKS,
    DriveFit,
    LevelModel,
    block_rows,
    drive_and_delay,
    prepare,
)
from drafttwin.sliver.leveller_record import LevellerRecord, LevellerSetting
from drafttwin.sliver.sensor import SliverSensor
from drafttwin.sliver.staple import StapleDiagram

SEARCH_MM = 120.0
"""Action points searched either side of the current setting, mm."""
PRECISION_MM = 5.0
"""Half-width of the interval that counts as found (``metres_needed``), mm."""
RESAMPLES = 400


@dataclass(frozen=True)
class ExpectedEvenness:
    """Count and CVs of a delivered sliver as the delivery sensor reads it."""

    count_ktex: float
    cv_pct: float
    cv_1m_pct: float
    cv_3m_pct: float
    cv_5m_pct: float

    @classmethod
    def of(cls, ktex: np.ndarray, step_m: float) -> ExpectedEvenness:
        ev = evenness(ktex, step_m)
        cut = ev.cv_cut_pct
        return cls(ev.count_ktex, ev.cv_pct, cut["1 m"], cut["3 m"], cut["5 m"])


@dataclass(frozen=True)
class LevellingAdvice:
    """The action point and intensity a record recommends, and what they are expected to
    give (JSON: :meth:`to_dict`).

    Attributes:
        recommended_action_point_mm: the setting of the least expected CV, mm of fed sliver
            from the scanning rollers (the machine's frame).
        action_point_interval_mm: its 95 % interval (block bootstrap), mm.
        recommended_intensity: the intensity of the least expected CV there.
        intensity_interval: its 95 % interval.
        current_action_point_mm: the record's setting (None without a leveller).
        current_intensity: the record's intensity (0 without a leveller).
        current: the evenness the record has (the delivery sensor's readings).
        recommended: the evenness expected at the recommendation.
        estimated_action_point_mm: where the fed material's mass reaches the delivery, mm
            from the scanning rollers (the setting of a drive without lag).
        drive_time_constant_s: the regulating drive's time constant that explains the record.
        drive_time_constant_interval_s: its 95 % interval (block bootstrap), s.
        metres_used: delivered sliver analysed, m.
        metres_needed: the shortest part of it (from its start, in 5-m steps) from which on
            the interval is within +-5 mm; None if the record is too short for that, or does
            not place the action point (``identifiable`` false).
        identifiable: whether the record says where the action point is (interval within
            +-25 mm).
        notes: what the reader should know (drifts, a drive slower than its nominal, ...).
    """

    recommended_action_point_mm: float
    action_point_interval_mm: tuple[float, float]
    recommended_intensity: float
    intensity_interval: tuple[float, float]
    current_action_point_mm: float | None
    current_intensity: float
    current: ExpectedEvenness
    recommended: ExpectedEvenness
    estimated_action_point_mm: float
    drive_time_constant_s: float
    drive_time_constant_interval_s: tuple[float, float]
    metres_used: float
    metres_needed: float | None
    identifiable: bool
    notes: tuple[str, ...] = field(default_factory=tuple)

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["action_point_interval_mm"] = list(self.action_point_interval_mm)
        out["intensity_interval"] = list(self.intensity_interval)
        out["drive_time_constant_interval_s"] = list(self.drive_time_constant_interval_s)
        out["notes"] = list(self.notes)
        return out


def find_action_point(record: LevellerRecord, setting: LevellerSetting,
                      staple: StapleDiagram | None = None, sensor: SliverSensor | None = None,
                      *, search_mm: float = SEARCH_MM, seed: int = 0) -> LevellingAdvice:  # fmt: skip
    """The action point and intensity of the least expected CV from a levelling record (see
    the module's docstring). ``setting`` is the record's (intensity 0: a record without a
    leveller, whose action point then only centres the search); ``staple`` the fibres
    (default cotton) and ``sensor`` the delivery sensor (default the plant's), for the
    smoothing of a correction."""
    staple = staple or StapleDiagram.preset("cotton")
    sensor = sensor or SliverSensor()
    centre = setting.action_point_mm
    grid = np.arange(centre - search_mm, centre + search_mm + 0.5, 1.0)
    grid = grid[grid > 0]
    model = prepare(record, setting, staple, sensor, float(grid[-1]))
    y = model.log_y[model.start :]
    drive = drive_and_delay(model, setting, grid, staple, seed)
    tau, material = drive.time_constant_s, drive.material_action_point_mm
    current = _Setting(model, centre, setting.intensity, tau)
    z = y - current.effect
    linear = _block_sums(model, z, grid, tau, record.step_m)
    gains = np.clip(_gains(linear.sum(axis=1)), 0.0, 2.0)
    rows = block_rows(z.size, record.step_m)
    exact = np.stack([_weighted_sums(model, z, current, _Setting(model, float(a), float(g), tau),
                                     rows) for a, g in zip(grid, gains, strict=True)])  # fmt: skip
    best = _least(exact.sum(axis=1))
    action = float(np.interp(best, np.arange(grid.size), grid))
    intensity = _best_intensity(
        model, z, current, action, tau, float(np.interp(best, np.arange(grid.size), gains))
    )
    rng = np.random.default_rng(seed)
    counts = rng.multinomial(exact.shape[1], np.full(exact.shape[1], 1 / exact.shape[1]), RESAMPLES)
    picks = np.array([_least(np.einsum("b,gbk->gk", c, exact)) for c in counts])
    lo, hi = np.interp(np.percentile(picks, [2.5, 97.5]), np.arange(grid.size), grid)
    boot_gain = [_argmin(np.einsum("b,gbk->gk", c, linear))[1] for c in counts]
    g_lo, g_hi = np.clip(np.percentile(boot_gain, [2.5, 97.5]), 0.0, 2.0)
    new = _Setting(model, action, intensity, tau)
    limits = _limits(record, model, grid, best, drive.transit_mm, float(g_lo))
    current_ev = ExpectedEvenness.of(record.delivery_ktex[model.start :], record.step_m)
    expected = ExpectedEvenness.of(_counterfactual(model, z, current, new, record.step_m),
                                   record.step_m)  # fmt: skip
    return LevellingAdvice(
        recommended_action_point_mm=action,
        action_point_interval_mm=(float(lo), float(hi)),
        recommended_intensity=intensity,
        intensity_interval=(float(g_lo), float(g_hi)),
        current_action_point_mm=centre if setting.intensity > 0 else None,
        current_intensity=setting.intensity,
        current=current_ev,
        recommended=expected,
        estimated_action_point_mm=material,
        drive_time_constant_s=tau,
        drive_time_constant_interval_s=drive.interval_s,
        metres_used=record.length_m,
        # never "found within +-5 mm" where the record does not place it (a stuck infeed
        # sensor had 52 m beside an interval of the whole search)
        metres_needed=_metres_needed(exact, grid, rng, record.step_m, rows, model.start)
        if bool(hi - lo <= 50.0) and not limits
        else None,
        identifiable=bool(hi - lo <= 50.0) and not limits,
        notes=limits + _notes(setting, drive, record, model) + _longer(current_ev, expected),
    )


@dataclass(frozen=True)
class _Setting:
    """A setting's factor and its effect on the delivered log-mass, analysis window."""

    factor: np.ndarray  # the drive's speed factor at each row
    effect: np.ndarray  # K * log f

    def __init__(self, model: LevelModel, action_mm: float, intensity: float, tau_s: float) -> None:
        if intensity <= 0:
            n = model.log_y.size - model.start
            object.__setattr__(self, "factor", np.ones(n))
            object.__setattr__(self, "effect", np.zeros(n))
            return
        log_f = model.log_factor(action_mm, intensity, tau_s)
        object.__setattr__(self, "factor", np.exp(log_f[model.start :]))
        u = lfilter(model.kernel, [1.0], log_f)
        object.__setattr__(self, "effect", np.asarray(u[model.start :]))


def _delivered(z: np.ndarray, current: _Setting, new: _Setting) -> tuple[np.ndarray, np.ndarray]:
    """The delivered sliver of another setting, per row of the record: its relative mass
    ``exp(z + K * log f_new)`` and the delivered length each row becomes, relative to the
    record's (``f_cur / f_new``: a row is a fixed piece of fed sliver, the draft is the
    drive's factor's inverse)."""
    return np.exp(z + new.effect), current.factor / new.factor


def _weighted_sums(model: LevelModel, z: np.ndarray, current: _Setting, new: _Setting,
                   rows: int) -> np.ndarray:  # fmt: skip
    """Per block of ``rows``: delivered length, mass x length and mass^2 x length of a
    setting."""
    y, w = _delivered(z, current, new)
    n_blocks = max(z.size // rows, 1)
    rows = min(rows, z.size)
    cut = n_blocks * rows
    yb, wb = y[:cut].reshape(n_blocks, rows), w[:cut].reshape(n_blocks, rows)
    return np.stack([wb.sum(1), (wb * yb).sum(1), (wb * yb * yb).sum(1)], axis=1)


def _cv2(sums: np.ndarray) -> np.ndarray:
    """CV^2 from (length, mass x length, mass^2 x length) sums, ``(..., 3)``."""
    mean = sums[..., 1] / sums[..., 0]
    return np.asarray(sums[..., 2] / sums[..., 0] / mean**2 - 1.0)


def _least(sums: np.ndarray) -> float:
    """The (fractional) grid index of the least CV: ``sums`` ``(grid, 3)``."""
    return _parabola_min(_cv2(sums))


def _parabola_min(values: np.ndarray) -> float:
    k = int(np.argmin(values))
    if 0 < k < values.size - 1:  # a parabola through the least three
        den = values[k - 1] - 2 * values[k] + values[k + 1]
        if den > 0:
            return float(k + 0.5 * (values[k - 1] - values[k + 1]) / den)
    return float(k)


def _best_intensity(model: LevelModel, z: np.ndarray, current: _Setting, action: float, tau: float,
                    start: float) -> float:  # fmt: skip
    """The intensity of the least CV at ``action`` (Brent within 0-2, from ``start``)."""
    from scipy.optimize import minimize_scalar

    def cv2(i: float) -> float:
        new = _Setting(model, action, i, tau)
        return float(_cv2(_weighted_sums(model, z, current, new, z.size)[0]))

    lo, hi = max(0.0, start - 0.3), min(2.0, start + 0.3)
    res = minimize_scalar(cv2, bounds=(lo, hi), method="bounded", options={"xatol": 1e-3})
    return float(res.x)


def _counterfactual(model: LevelModel, z: np.ndarray, current: _Setting, new: _Setting,
                    step_m: float) -> np.ndarray:  # fmt: skip
    """The delivered sliver of another setting on the record's even grid, ktex."""
    y, w = _delivered(z, current, new)
    s = np.cumsum(w) * step_m
    even = np.arange(s[0], s[-1], step_m)
    return np.asarray(np.interp(even, s, y) * math.exp(model.log_mean))


def _gains(sums: np.ndarray) -> np.ndarray:
    """The intensity of the least variance of ``z - I v`` at each grid point (first order)."""
    n, sz, sv, _, szv, svv = (sums[:, k] for k in range(6))
    cov = szv / n - sz * sv / n**2
    return np.asarray(cov / np.maximum(svv / n - (sv / n) ** 2, 1e-300))


def _block_sums(model: LevelModel, z: np.ndarray, grid: np.ndarray, tau: float,
                step_m: float) -> np.ndarray:  # fmt: skip
    """Per action point and block: n, sum z, sum v, sum z^2, sum z v, sum v^2, with ``v``
    the first-order effect of unit intensity (``Y' = z - I v``)."""
    rows = block_rows(z.size, step_m)
    n_blocks = max(z.size // rows, 1)
    cut = n_blocks * rows
    zb = z[:cut].reshape(n_blocks, rows)
    out = np.empty((grid.size, n_blocks, 6))
    for i, a in enumerate(grid):
        v = model.linear(float(a), tau)[:cut].reshape(n_blocks, rows)
        out[i] = np.stack([np.full(n_blocks, float(rows)), zb.sum(1), v.sum(1), (zb * zb).sum(1),
                           (zb * v).sum(1), (v * v).sum(1)], axis=1)  # fmt: skip
    return out


def _argmin(sums: np.ndarray) -> tuple[float, float]:
    """The (fractional) grid index of the least variance of ``z - I v`` with the best ``I``
    at each point (first order), and that ``I`` there: ``sums`` ``(grid, 6)``."""
    n, sz, sv, szz, szv, svv = (sums[:, k] for k in range(6))
    gain = _gains(sums)
    resid = szz / n - (sz / n) ** 2 - (szv / n - sz * sv / n**2) * gain
    frac = _parabola_min(resid)
    return frac, float(np.interp(frac, np.arange(gain.size), gain))


def _metres_needed(sums: np.ndarray, grid: np.ndarray, rng: np.random.Generator,
                   step_m: float, rows: int, head: int) -> float | None:  # fmt: skip
    """The shortest head of the record (whole blocks of ``rows``, after the ``head`` rows the
    store's reach takes) from which on the bootstrap interval of the action point is within
    +-PRECISION_MM (``sums``: the blocks' weighted sums), m of sliver."""
    n_blocks = sums.shape[1]
    ok = np.zeros(n_blocks + 1, dtype=bool)
    for k in range(2, n_blocks + 1):
        part = sums[:, :k]
        counts = rng.multinomial(k, np.full(k, 1 / k), RESAMPLES // 2)
        picks = [_least(np.einsum("b,gbk->gk", c, part)) for c in counts]
        lo, hi = np.interp(np.percentile(picks, [2.5, 97.5]), np.arange(grid.size), grid)
        ok[k] = hi - lo <= 2 * PRECISION_MM
    for k in range(MIN_BLOCKS, n_blocks + 1):
        if ok[k:].all():
            return float((head + k * rows) * step_m)
    return None


def _limits(record: LevellerRecord, model: LevelModel, grid: np.ndarray, best: float,
            transit_mm: float, intensity_low: float) -> tuple[str, ...]:  # fmt: skip
    """Why the record cannot place the action point, if it cannot: a reading that does not
    vary, or one that does not explain the delivered count (the intensity's 95 % interval
    reaches 0: no correction is shown to help anywhere; a dead infeed sensor reading noise
    got intensity 2 and a 54-mm move for a CV of 1.273 -> 1.267 %), or an optimum (or the
    material's delay) on the edge of the searched range, where the true one may lie beyond
    it."""
    infeed = record.infeed_ktex[model.start :]
    if float(np.std(infeed)) <= 1e-6 * abs(float(np.mean(infeed))):
        return ("the infeed reading does not vary (a stuck infeed sensor?): nothing in the "
                "record places the action point",)  # fmt: skip
    if intensity_low <= 0.0:
        return ("the infeed reading does not explain the delivered count (the intensity's "
                "95 % interval reaches 0: a dead or disconnected infeed sensor?): nothing in "
                "the record places the action point",)  # fmt: skip
    span = f"{grid[0]:.0f}-{grid[-1]:.0f} mm"
    if best < 0.5 or best > grid.size - 1.5:
        return (f"the least CV lies on the edge of the searched range ({span}): the action "
                "point may lie beyond it; search a wider range",)  # fmt: skip
    if transit_mm <= grid[0] + 1.0 or transit_mm >= grid[-2] - 1.0:
        return (f"the material's delay lies on the edge of the searched range ({span}): "
                "search a wider range",)  # fmt: skip
    return ()


NOTES_MIN_M = 40.0
"""Analysed sliver (after the store's reach) below which the drive and the count's drift are
not judged: on 3-8 m windows the count's slope over them read as -13 to +98 % per 100 m."""

LONGER_WORSE = 1.05
"""A recommendation whose CV(3 m) or CV(5 m) exceeds the current one's by this factor is
said to (the search minimises the point CV: with a sluggish drive it can trade the long
lengths for the short ones, 0.038 -> 0.069 % at 5 m on a 25-ms drive)."""


def _longer(current: ExpectedEvenness, expected: ExpectedEvenness) -> tuple[str, ...]:
    """A note where the recommendation raises the CV over 3 m or 5 m (else none)."""
    worse = [f"CV({m}) {a:.3f} -> {b:.3f} %"
             for m, a, b in (("3 m", current.cv_3m_pct, expected.cv_3m_pct),
                             ("5 m", current.cv_5m_pct, expected.cv_5m_pct))
             if math.isfinite(a) and math.isfinite(b) and b > LONGER_WORSE * a]  # fmt: skip
    if not worse:
        return ()
    return (f"the recommendation lowers the CV but raises it over longer lengths ({'; '.join(worse)}): "
            "the search minimises the CV; where the count over metres matters more (the next "
            "passage doubles slivers), weigh it before taking the setting",)  # fmt: skip


def _notes(
    setting: LevellerSetting, drive: DriveFit, record: LevellerRecord, model: LevelModel
) -> tuple[str, ...]:
    out = []
    tau, (tau_lo, tau_hi) = drive.time_constant_s, drive.interval_s
    s = record.delivered_length_m[model.start :]
    y = record.delivery_ktex[model.start :]
    if s[-1] - s[0] < NOTES_MIN_M:  # a slope over 3 m read as +98 % per 100 m
        return ("the record is too short to judge the drive or a drift of the count "
                f"({s[-1] - s[0]:.0f} m analysed, {NOTES_MIN_M:g} m needed)",) + (
            ("the record has no leveller: the recommendation is a first setting",)
            if setting.intensity == 0 else ())  # fmt: skip
    slope = float(np.polyfit(s - s.mean(), y / y.mean(), 1)[0]) * 100 * 100
    drifting = abs(slope) > 0.3
    # sluggish only where the whole interval says so (a 5-ms drive read 0-10 ms)
    if setting.intensity > 0 and tau_lo > 2 * setting.drive_time_constant_s + 0.002:
        edge = " at least" if tau >= max(DRIVE_GRID_S) else ""
        out.append(
            f"the regulating drive follows with{edge} {1000 * tau:.0f} ms (95 % "
            f"{1000 * tau_lo:.0f}-{1000 * tau_hi:.0f} ms), its nominal is "
            f"{1000 * setting.drive_time_constant_s:.0f} ms: "
            + ("a sluggish drive, or the count's drift below read as one (a drifting infeed "
               "sensor of 2-3 % a minute was: check the drive before replacing it; the "
               "action point is less sure then)" if drifting else "a sluggish drive")
        )  # fmt: skip
    if drifting:
        out.append(f"the delivered count drifts by {slope:+.2f} % per 100 m: a drifting infeed "
                   "sensor or a count change of the feed (a levelled count follows the infeed "
                   "sensor's gain)")  # fmt: skip
    if setting.intensity == 0:
        out.append("the record has no leveller: the recommendation is a first setting")
    return tuple(out)


__all__ = ["ExpectedEvenness", "LevellerRecord", "LevellerSetting", "LevellingAdvice",
           "find_action_point"]  # fmt: skip
