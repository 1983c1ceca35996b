"""The drafting simulator: fed slivers and roller speeds in, the delivered sliver out.

:func:`draft` draws the fibres of the feed (:mod:`drafttwin.sliver.feed`), carries each
through the three zones of the drafting arrangement by the rollers' surface speeds
(:mod:`drafttwin.sliver.speeds`) and deposits it on a delivered-length grid
(:mod:`drafttwin.sliver.kernel`). Ideal drafting, the exact core: a fibre changes speed when
its leading end reaches the next nip. :class:`RealDrafting` is an option for floating fibres
whose acceleration point is pulled forward by the fibres already fast around them; its two
parameters are not known for any machine and must be calibrated against a mill's
spectrograms (docs/sliver.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drafttwin.errors import ConfigError
from drafttwin.sliver import kernel as K
from drafttwin.sliver.feed import Feed
from drafttwin.sliver.leveller import Autoleveller
from drafttwin.sliver.record import Sliver
from drafttwin.sliver.speeds import SurfaceSpeeds

FED_STEP_MM = 0.1
"""Step of the fed-length grid on which the feed's rate and the transport map are
tabulated, mm (0.66 mm of delivered sliver at a draft of 6.6)."""
PIECE_M = 2.0
"""Fed length per kernel call, m (progress and interruption between calls; the sliver does
not depend on it)."""


@dataclass(frozen=True)
class DraftingZones:
    """Nip-to-nip distances (gauges) of the three zones, mm.

    FA320A defaults (assumption: the machine's settings are not published; a 4-over-4
    drawframe for cotton runs its zones a few mm longer than the fibres' upper length):
    main zone (front-second) 44 mm, middle zone (second-third) 40 mm, break zone
    (third-back) 46 mm.
    """

    main_mm: float = 44.0
    middle_mm: float = 40.0
    break_mm: float = 46.0

    def __post_init__(self) -> None:
        for name, g in (("main", self.main_mm), ("middle", self.middle_mm),
                        ("break", self.break_mm)):  # fmt: skip
            if not 5.0 <= g <= 500.0:
                raise ConfigError(f"{name} zone gauge {g} mm", where="--gauges",
                                  fix="give gauges of 5-500 mm")  # fmt: skip

    def array(self) -> np.ndarray:
        return np.array([self.main_mm, self.middle_mm, self.break_mm])

    @property
    def total_mm(self) -> float:
        return self.main_mm + self.middle_mm + self.break_mm


@dataclass(frozen=True)
class RealDrafting:
    """Floating fibres accelerate before the front nip, pulled by fibres already fast.

    A fibre shorter than the main gauge accelerates a distance ``X`` before the front nip
    and lands ``(D_main - 1) X`` earlier on the delivered sliver. ``X`` is
    ``acceleration_mm * 2U * (1 + coupling * (c - 1))``: ``U`` uniform (an independent
    spread, which alone adds no irregularity to a random sliver) and ``c`` the density of
    fibres already delivered over the fibre's length ahead of it relative to the mean (in
    ideal drafting): fibres in a thick place are dragged forward together, which makes the
    drafting wave. Both parameters must be calibrated against measured spectrograms.
    """

    acceleration_mm: float = 8.0
    coupling: float = 1.0

    def __post_init__(self) -> None:
        if not (0 <= self.acceleration_mm <= 200 and 0 <= self.coupling <= 20):
            raise ConfigError(f"real drafting acceleration {self.acceleration_mm} mm, "
                              f"coupling {self.coupling}", where="--real-drafting",
                              fix="acceleration 0-200 mm, coupling 0-20")  # fmt: skip


def draft(speeds: SurfaceSpeeds, feed: Feed, zones: DraftingZones | None = None, *,
          step_mm: float = 1.0, seed: int = 0, fibre_scale: float = 1.0,
          real: RealDrafting | None = None, keep_fibres: int = 0,
          leveller: Autoleveller | None = None,
          progress: Callable[[float], None] | None = None) -> Sliver:  # fmt: skip
    """Draft ``feed`` through the zones at ``speeds``; the delivered sliver on a grid of
    ``step_mm`` from the front roller's position at the first time point.

    ``leveller`` levels the feed through the main draft (:mod:`drafttwin.sliver.leveller`).
    ``fibre_scale`` lumps that many fibres into one heavier fibre (faster; the random part's
    variance grows by the same factor, which the sliver records for its evenness and its
    ideal curve). ``keep_fibres`` keeps the first so many drafted fibres for a later passage
    (:func:`draft_fibres`). ``progress`` is called with metres of fed sliver done.
    """
    zones = zones or DraftingZones()
    _check(step_mm, fibre_scale, speeds)
    surface = _with_run_in(speeds, zones, feed)
    h, n_bins = step_mm, int(math.floor(speeds.delivered_length_m * 1e3 / step_mm))
    if n_bins < 10:
        raise ConfigError(f"the speeds deliver only {speeds.delivered_length_m:.3g} m of "
                          "sliver", where="--duration", fix="give a longer record")  # fmt: skip
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
    quantiles, cum, p0, relative = _tables(feed, surface, zones, rng,
                                           extra=0.0 if leveller is None else 1.0)  # fmt: skip
    p_grid = p0 + FED_STEP_MM * np.arange(cum.size)
    times = _times(speeds, surface)
    levelling = None
    if leveller is not None:
        sensor_rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(3)[2])
        surface, levelling = leveller.levelled(surface, times, p_grid, relative, feed.staple,
                                               zones.array(), sensor_rng)  # fmt: skip
    lead = K.transport_map(surface, zones.array(), p_grid)
    run = _Run(seed, lead, quantiles, cum, p0, fibre_scale, h, n_bins, keep_fibres, progress,
               real is not None)  # fmt: skip
    diff, kept, count = run(np.empty(0))
    if real is not None and real.acceleration_mm > 0:
        diff, kept, count = run(_drift_table(real, diff, speeds, zones, h))
    tex = np.cumsum(diff[:-2])
    s_mid = (np.arange(n_bins) + 0.5) * h
    t = np.interp(s_mid, surface[:, K.FRONT], times)
    return Sliver(tex / 1000.0, step_mm * 1e-3, time_s=t, staple=feed.staple,
                  fibre_scale=fibre_scale,
                  info={"fibres": count, "seed": seed, "speeds": speeds.source,
                        "drafts": speeds.drafts(), "feed_ktex": feed.total_ktex,
                        "doublings": feed.doublings,
                        "drafting": "ideal" if real is None else "real",
                        "leveller": None if leveller is None or levelling is None
                        else leveller.record(levelling.true_action_point_mm)},
                  fibres=kept, fed=(p0, FED_STEP_MM, relative), levelling=levelling)  # fmt: skip


@dataclass(frozen=True)
class _Run:
    """One drafting pass in pieces of :data:`PIECE_M` of fed sliver."""

    seed: int
    lead: np.ndarray
    quantiles: np.ndarray
    cum: np.ndarray
    p0: float
    fibre_scale: float
    h: float
    n_bins: int
    keep_fibres: int
    progress: Callable[[float], None] | None
    real: bool

    def __call__(self, drift: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, int]:
        diff = np.zeros(self.n_bins + 2)
        keep = np.zeros((self.keep_fibres, 3))
        state = np.zeros(len(K.STATE))
        p_end = self.p0 + FED_STEP_MM * (self.cum.size - 1)
        p_stop = self.p0
        rng = np.random.default_rng(np.random.SeedSequence(self.seed).spawn(2)[1])
        while state[K.STATE.index("done")] == 0.0 and p_stop < p_end:
            p_stop = min(p_stop + PIECE_M * 1e3, p_end)
            feed = np.array([self.p0, FED_STEP_MM, self.fibre_scale, p_stop, float(self.real)])
            K.draft_random(rng, self.lead, self.quantiles, self.cum, feed, drift, self.h,
                           diff, keep, state)  # fmt: skip
            if self.progress is not None:
                self.progress(PIECE_M)
        count = int(state[K.STATE.index("count")])
        kept = keep[: min(count, self.keep_fibres)] if self.keep_fibres else None
        return diff, kept, count


def _check(step_mm: float, fibre_scale: float, speeds: SurfaceSpeeds) -> None:
    if not 0.05 <= step_mm <= 50:
        raise ConfigError(f"grid step {step_mm} mm", where="--step-mm", fix="use 0.05-50 mm")
    if not 1 <= fibre_scale <= 1e6:
        raise ConfigError(f"fibre scale {fibre_scale}", where="--fibre-scale",
                          fix="1 (every fibre) or more (lumped fibres)")  # fmt: skip
    if speeds.delivered_length_m <= 0 or np.any(speeds.length_m[-1] - speeds.length_m[0] <= 0):
        raise ConfigError("a roller does not turn over the record", source=speeds.source or None,
                          fix="give a record in which the frame runs")  # fmt: skip


def _with_run_in(speeds: SurfaceSpeeds, zones: DraftingZones, feed: Feed) -> np.ndarray:
    """Surface lengths in mm, 0 at the record's first point, preceded by a run-in at the
    record's mean speeds long enough to fill the zones with drafted fibres."""
    longest = float(feed.staple.lengths_mm[-1] + feed.staple.class_width_mm)
    return _with_run_in_for(speeds, zones, longest)


def _times(speeds: SurfaceSpeeds, surface: np.ndarray) -> np.ndarray:
    n_before = (surface.shape[0] - speeds.time_s.size) // 2
    times: np.ndarray = speeds.time_s[0] + speeds.step_s * (np.arange(surface.shape[0]) - n_before)
    return times


def _tables(feed: Feed, surface: np.ndarray, zones: DraftingZones, rng: np.random.Generator,
            extra: float = 0.0) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:  # fmt: skip
    """Inverse CDFs (length, fineness), the feed's cumulative rate on the fed-length grid,
    the grid's start (mm) and the feed's relative rate on it; ``extra``: that fraction more
    fed length (a leveller may run the feeding rollers faster)."""
    p0 = float(surface[0, K.BACK]) - zones.break_mm
    size = int(math.ceil((float(surface[-1, K.BACK]) - p0) * (1 + extra) / FED_STEP_MM)) + 2
    relative = feed.intensity(p0, FED_STEP_MM, size, rng)
    rate = relative * feed.fibres_per_mm()
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * FED_STEP_MM)])
    quantiles = np.vstack([feed.staple.length_quantiles(), feed.staple.fineness_quantiles()])
    return quantiles, cum, p0, relative


def _drift_table(real: RealDrafting, diff: np.ndarray, speeds: SurfaceSpeeds,
                 zones: DraftingZones, h: float) -> np.ndarray:  # fmt: skip
    """The real-drafting table of :func:`drafttwin.sliver.kernel._early`: parameters, then
    the ideal sliver's cumulative mass per grid point."""
    ideal = np.cumsum(diff[:-2])
    cum = np.concatenate([[0.0], np.cumsum(ideal)])
    rho_mean = float(ideal.mean())
    head = [real.acceleration_mm, real.coupling, speeds.drafts()["main"], rho_mean, zones.main_mm]
    return np.concatenate([head, cum])


def draft_fibres(fibres: np.ndarray, speeds: SurfaceSpeeds, zones: DraftingZones | None = None,
                 *, step_mm: float = 1.0) -> Sliver:  # fmt: skip
    """A later passage: draft the fibres kept from an earlier one (``Sliver.fibres``:
    leading end on that sliver, length, tex), which keeps their arrangement, so a wave
    hidden by fibre overlap in the earlier sliver shows once it is stretched beyond the
    fibres (research/sliver.md 4.5)."""
    zones = zones or DraftingZones()
    if fibres is None or fibres.ndim != 2 or fibres.shape[1] != 3 or fibres.shape[0] < 100:
        raise ConfigError("no fibres kept from the earlier passage",
                          fix="draft it with keep_fibres > 0")  # fmt: skip
    fibres = fibres[fibres[:, 0] >= 0.0]  # the earlier run-in is not part of its sliver
    order = np.argsort(fibres[:, 0], kind="stable")
    lead, lengths, tex = (np.ascontiguousarray(fibres[order, k]) for k in range(3))
    surface = _with_run_in_for(speeds, zones, float(lengths.max()))
    lead = lead - lead[0] + float(surface[0, K.BACK]) - zones.break_mm
    n_bins = int(math.floor(speeds.delivered_length_m * 1e3 / step_mm))
    diff = np.zeros(n_bins + 2)
    out_lead = np.empty_like(lead)
    count = K.draft_given(lead, lengths, tex, surface, zones.array(), step_mm, diff, out_lead)
    delivered = out_lead[np.isfinite(out_lead)]
    end = min(n_bins, int((delivered.max() - lengths.max()) / step_mm)) if count else 0
    if end < 10:
        raise ConfigError("the kept fibres do not reach the delivery within these speeds",
                          fix="keep more fibres or give shorter speeds")  # fmt: skip
    tex_grid = np.cumsum(diff[:-2])[:end]
    return Sliver(tex_grid / 1000.0, step_mm * 1e-3, info={"fibres": int(count),
                  "speeds": speeds.source, "drafts": speeds.drafts(), "passage": "later"})  # fmt: skip


def _with_run_in_for(speeds: SurfaceSpeeds, zones: DraftingZones, longest_mm: float) -> np.ndarray:
    """Surface lengths (mm, 0 at the record's first point) with a run-in before the record
    and a run-out after it at the record's mean speeds: the zones are full of fibres at its
    start, and fibres that land early (real drafting) still come after its end."""
    s = (speeds.length_m - speeds.length_m[0]) * 1e3
    v = s[-1] / speeds.duration_s
    run_in_s = (zones.total_mm + 2 * longest_mm + 10.0) / v[K.BACK]
    n = int(math.ceil(run_in_s / speeds.step_s)) + 1
    before = -v[None, :] * speeds.step_s * np.arange(n, 0, -1)[:, None]
    after = s[-1][None, :] + v[None, :] * speeds.step_s * np.arange(1, n + 1)[:, None]
    return np.ascontiguousarray(np.vstack([before, s, after]))
