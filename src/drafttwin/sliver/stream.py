"""Drafting as the rollers turn: a running machine's sliver, a piece at a time.

:class:`StreamDrafting` takes the bottom rollers' cumulative surface lengths as a running
machine produces them (any number of rows at a time, on one uniform time grid) and hands back
the delivery sensor's readings of the bins no fibre can reach any more, each with the infeed
scanning rollers' reading held then and the store's length clock: what a levelling drawframe
records, as :func:`drafttwin.plant.sliver_channel.make_sliver` writes it for a whole record.

It is the offline simulator's physics, continued from piece to piece: the zones' transport
map (:func:`~drafttwin.sliver.kernel.transport_map`), the fibres drawn and deposited one at a
time (:func:`~drafttwin.sliver.kernel.draft_random`, its state and random generator carried),
the leveller step by step (:func:`~drafttwin.sliver.kernel.level_surface`, its drive's factor
carried), the infeed and delivery sensors of :mod:`drafttwin.sliver.leveller` and
:mod:`drafttwin.sliver.sensor`; the feed comes from :class:`~drafttwin.sliver.feed.FeedStream`.
Before the first row the machine is taken to have run at the first piece's speeds (the zones
full of fibres), as the offline simulator's run-in at a record's mean speeds. Fed the same
surfaces and feed, the two give the same sliver to rounding (tests/sliver/test_stream.py).

Memory stays bounded: what no fibre, reading or bin needs any more is dropped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.signal import lfilter

from drafttwin.errors import ConfigError
from drafttwin.sliver import kernel as K
from drafttwin.sliver.drafting import FED_STEP_MM, DraftingZones
from drafttwin.sliver.feed import Feed, FeedStream
from drafttwin.sliver.leveller import (
    MAX_FACTOR,
    MIN_FACTOR,
    Autoleveller,
    InfeedSensor,
    mass_kernel,
    true_action_point_mm,
)
from drafttwin.sliver.sensor import SliverSensor

FEED_CHUNK = 4000
"""Fed grid points generated at a time (400 mm of fed sliver)."""
SAFE_DRAWS = 50.0
"""The fibres' draws stop this many expected fibres short of the transport map's end (a draw
past its end would end the feed)."""


@dataclass(frozen=True)
class StreamPiece:
    """What one piece of running delivered.

    Attributes:
        delivered_m, ktex, time_s: the delivery sensor's readings (m from the stream's start,
            ktex, s on the caller's clock).
        infeed_ktex: the infeed scanning rollers' reading held at each of them, ktex.
        fed_length_m: the store's length clock (the feeding roller's travel from the
            stream's start), m.
        true_start_m, true_ktex: the true sliver's bins completed (their first bin's start,
            m, and the bins' linear density, ktex, on the drafting grid).
    """

    delivered_m: np.ndarray
    ktex: np.ndarray
    time_s: np.ndarray
    infeed_ktex: np.ndarray
    fed_length_m: np.ndarray
    true_start_m: float
    true_ktex: np.ndarray


class StreamDrafting:
    """A running machine's drafting arrangement, sensors and leveller (see the module).

    Args:
        feed: the fed slivers.
        zones: the gauges.
        step_mm: the drafting grid, mm of delivered sliver.
        seed: draws the feed, the fibres and the sensors' noise (the fibres and the infeed
            sensor's noise as :func:`~drafttwin.sliver.drafting.draft` draws them).
        fibre_scale: fibres lumped into one.
        leveller: the autoleveller (None: none; the infeed sensor reads all the same).
        delivery: the delivery sensor.
        infeed: the infeed scanning rollers (the leveller's own where there is one).
    """

    def __init__(self, feed: Feed, zones: DraftingZones | None = None, *, step_mm: float = 1.0,
                 seed: int = 0, fibre_scale: float = 1.0, leveller: Autoleveller | None = None,
                 delivery: SliverSensor | None = None,
                 infeed: InfeedSensor | None = None) -> None:  # fmt: skip
        if not (0.05 <= step_mm <= 50 and 1 <= fibre_scale <= 1e6):
            raise ConfigError(f"grid step {step_mm} mm, fibre scale {fibre_scale}",
                              where="--fibre-scale", fix="a step of 0.05-50 mm, a fibre scale "
                              "of 1 (every fibre) or more")  # fmt: skip
        self.feed, self.zones = feed, zones or DraftingZones()
        self.h, self.scale = float(step_mm), float(fibre_scale)
        self.leveller = leveller
        self.delivery = delivery or SliverSensor()
        self.infeed = leveller.sensor if leveller is not None else infeed or InfeedSensor()
        seq = np.random.SeedSequence(seed).spawn(4)  # feed, fibres, infeed noise, delivery
        self._rng_feed, self._rng_fibres, self._rng_infeed, self._rng_delivery = (
            np.random.default_rng(s) for s in seq)  # fmt: skip
        self._quantiles = np.vstack([feed.staple.length_quantiles(),
                                     feed.staple.fineness_quantiles()])  # fmt: skip
        self._longest = float(feed.staple.lengths_mm[-1] + feed.staple.class_width_mm)
        self._kernel = mass_kernel(feed.staple, FED_STEP_MM)
        self._width = max(1, int(round(self.infeed.averaging_mm / FED_STEP_MM)))
        self.started = False
        self.true_action_point_mm: float | None = None
        self.action_point_mm: float | None = None
        self.bins = 0  # true bins completed
        self._sum = self._sum2 = 0.0

    # ---- the first piece -----------------------------------------------------------------
    def _start(self, time_s: np.ndarray, surface: np.ndarray) -> None:
        """Run-in rows at the first piece's speeds, the fed grid and the leveller's setting."""
        self._dt = float(time_s[1] - time_s[0])
        if not (self._dt > 0 and math.isfinite(self._dt)):
            raise ConfigError("the rollers' surfaces come on no increasing time grid",
                              where="surface")  # fmt: skip
        v = (surface[-1] - surface[0]) / (time_s[-1] - time_s[0])
        if not np.all(v > 0):
            raise ConfigError("a roller stands in the first piece", where="surface",
                              fix="start the sliver once the frame runs")  # fmt: skip
        self.t0 = float(time_s[0])
        run_in_s = (self.zones.total_mm + 2 * self._longest + 10.0) / v[K.BACK]
        n = int(math.ceil(run_in_s / self._dt)) + 1
        before = -v[None, :] * self._dt * np.arange(n, 0, -1)[:, None]
        self._rows_t = np.concatenate([-self._dt * np.arange(n, 0, -1), time_s - self.t0])
        self._U_last = before[0]  # the unlevelled surface's last row levelled so far
        self._S = before[:1].copy()  # levelled rows
        self._S_t = self._rows_t[:1].copy()
        self._pending = (before[1:], surface)
        self._n_run_in = n
        self._fed_speed = float(v[K.BACK])
        self._p0 = float(before[0, K.BACK]) - self.zones.break_mm
        self._stream = FeedStream(self.feed, self._p0, FED_STEP_MM, self._rng_feed)
        self._fpm = self.feed.fibres_per_mm()
        self._f0 = 0  # global index of the fed arrays' first element
        self._rel = np.empty(0)
        self._cum = np.empty(0)
        self._lead = np.empty(0)
        self._n_lead = 0
        self._cum_last, self._rate_last = 0.0, math.nan
        # the infeed sensor: mass (behind each place) and its contact average (centred)
        self._mass = np.empty(0)  # from global index self._m0
        self._m0 = 0
        self._n_seen = 0
        self._reads = np.empty(0)  # readings from global reading index self._r0
        self._r0 = 0
        self._pitch = self.infeed.pitch_mm
        self._q0 = self._p0  # fed position of reading 0
        # the fibres
        self._state = np.zeros(len(K.STATE))
        self._k = 0  # global fed index of the kernel's state
        self._bin0, self._diff, self._carry = 0, np.zeros(2), 0.0
        # the delivery sensor
        self._box_w = max(1, int(round(self.delivery.averaging_mm / self.h)))
        self._box_tail = np.empty(0)
        self._lag_y: float | None = None
        self._read_every = max(1, int(round(self.delivery.pitch_mm / self.h)))
        self._f = -1.0  # the regulating drive's factor
        if self.leveller is not None:
            drafts = {"break": float(v[K.THIRD] / v[K.BACK]),
                      "middle": float(v[K.SECOND] / v[K.THIRD])}  # fmt: skip
            true = true_action_point_mm(self.zones.array(), drafts, self.feed.staple,
                                        self.infeed.scan_ahead_mm)  # fmt: skip
            self.true_action_point_mm = true
            self.action_point_mm = self.leveller.setting_mm(true)
            tau = self.leveller.drive.time_constant_s
            self._drive_a = 1.0 if tau == 0 else -math.expm1(-self._dt / tau)
        self._back0: float | None = None  # the levelled back roller at t = 0
        self.started = True

    # ---- pieces --------------------------------------------------------------------------
    def push(self, time_s: np.ndarray, length_m: np.ndarray) -> StreamPiece:
        """The rollers' cumulative surface lengths (m, ``(n, 4)``: front, second, third, back)
        at the next times (s, uniform, continuing the grid of the earlier pieces); returns
        what is complete. The first piece needs two rows at least, all rollers turning."""
        t = np.asarray(time_s, dtype=np.float64)
        s = np.asarray(length_m, dtype=np.float64) * 1e3
        if s.ndim != 2 or s.shape != (t.size, 4) or not np.all(np.isfinite(s)):
            raise ConfigError("surface lengths must be finite, (n, 4) at n times",
                              where="surface")  # fmt: skip
        if not self.started:
            if t.size < 2:
                raise ConfigError("the first piece needs two rows", where="surface")
            self._origin = s[0].copy()
            self._start(t, s - self._origin)
            run_in, first = self._pending
            del self._pending
            self._level(np.vstack([run_in, first]), self._rows_t[1:])
        elif t.size:
            self._level(s - self._origin, t - self.t0)
        return self._draft()

    def _level(self, unlevelled: np.ndarray, times: np.ndarray) -> None:
        """Levelled rows (the leveller's drive factor on second, third and back roller)."""
        back_reach = float(self._S[-1, K.BACK]) + MAX_FACTOR * float(
            max(unlevelled[-1, K.BACK] - self._U_last[K.BACK], 0.0)
        )
        self._extend_feed(back_reach + self.infeed.scan_ahead_mm + self._kernel.size * 0.1
                          + 200.0)  # fmt: skip
        if self.leveller is None:
            levelled = unlevelled
        else:
            assert self.action_point_mm is not None
            surface = np.ascontiguousarray(np.vstack([self._U_last, unlevelled]))
            out = np.empty_like(surface)
            out[0] = self._S[-1]
            factor = np.empty(surface.shape[0])
            first = self._r0
            ahead = self.infeed.scan_ahead_mm - self.action_point_mm
            params = np.array([self._q0 + self._pitch * first, self._pitch, ahead,
                               self.leveller.intensity, self._drive_a, MIN_FACTOR, MAX_FACTOR,
                               self._f])  # fmt: skip
            K.level_surface(surface, self._reads, params, out, factor)
            self._f = float(factor[-1])
            levelled = out[1:]
        self._U_last = unlevelled[-1].copy()
        self._S = np.vstack([self._S, levelled])
        self._S_t = np.concatenate([self._S_t, times])
        if self._back0 is None and self._S_t[-1] >= 0.0:
            self._back0 = float(np.interp(0.0, self._S_t, self._S[:, K.BACK]))

    def _extend_feed(self, upto_mm: float) -> None:
        """Generate the feed (and the infeed sensor's readings of it) up to fed ``upto_mm``."""
        while self._p0 + FED_STEP_MM * (self._f0 + self._rel.size) < upto_mm:
            rel = self._stream.next(FEED_CHUNK)
            rate = rel * self._fpm
            prev = rate[0] if math.isnan(self._rate_last) else self._rate_last
            inc = 0.5 * (rate + np.concatenate([[prev], rate[:-1]])) * FED_STEP_MM
            if math.isnan(self._rate_last):
                inc[0] = 0.0  # cum starts at 0 at the grid's first point
            cum = np.cumsum(np.concatenate([[self._cum_last], inc]))[1:]
            self._cum_last, self._rate_last = float(cum[-1]), float(rate[-1])
            self._rel = np.concatenate([self._rel, rel])
            self._cum = np.concatenate([self._cum, cum])
            self._lead = np.concatenate([self._lead, np.full(rel.size, np.nan)])
            self._read_infeed()

    def _read_infeed(self) -> None:
        """The infeed readings whose inputs now exist (as InfeedSensor.readings computes them
        for a whole record: mass over the fibre lengths, the contact average, drift, noise)."""
        kn, half = self._kernel.size, self._width // 2
        end = self._f0 + self._rel.size  # global fed index generated
        lo = self._m0 + self._mass.size  # next mass index
        src_lo = lo - (kn - 1)
        if src_lo < 0:
            window = np.concatenate([np.full(-src_lo, self._rel[0]), self._rel[: end - self._f0]])
        else:
            window = self._rel[src_lo - self._f0 : end - self._f0]
        self._mass = np.concatenate([self._mass, np.convolve(window, self._kernel, "valid")])
        m_end = self._m0 + self._mass.size
        s_hi = m_end - (self._width - 1 - half)  # seen indices whose window lies inside
        if s_hi <= self._n_seen:
            return
        k_lo = self._r0 + self._reads.size
        q_first = int(math.floor((self._q0 + self._pitch * k_lo - self._p0) / FED_STEP_MM)) - 2
        w_lo = max(q_first - half - 1, self._m0, 0)  # the readings' averages all inside
        seen = uniform_filter1d(self._mass[w_lo - self._m0 :], self._width, mode="nearest")
        at = self._p0 + FED_STEP_MM * np.arange(w_lo, m_end)
        k_hi = int(math.floor((self._p0 + FED_STEP_MM * (s_hi - 1) - self._q0) / self._pitch))
        if k_hi > k_lo:
            q = self._q0 + self._pitch * np.arange(k_lo, k_hi)
            x = np.interp(q, at, seen)
            minutes = np.maximum(q - self.infeed.scan_ahead_mm, 0.0) / self._fed_speed / 60.0
            x = x * (1.0 + self.infeed.drift_pct_per_min / 100.0 * minutes)
            x = x * (1.0 + self.infeed.noise * self._rng_infeed.standard_normal(x.size))
            self._reads = np.concatenate([self._reads, x])
        self._n_seen = s_hi

    def _draft(self) -> StreamPiece:
        self._transport()
        a, b = self._k, self._n_lead
        cum = self._cum
        if b - a > 2:
            target = cum[b - 1 - self._f0] - SAFE_DRAWS * self.scale
            stop = int(np.searchsorted(cum, target, side="right")) - 1 + self._f0
            if stop > a:
                self._run_kernel(a, b, stop)
        return self._complete()

    def _transport(self) -> None:
        """The delivered position of every fed position the surfaces carry to the front nip."""
        n_all = self._f0 + self._rel.size
        if self._n_lead >= n_all:
            return
        p = self._p0 + FED_STEP_MM * np.arange(self._n_lead, n_all)
        back = self._S[:, K.BACK]
        r = max(int(np.searchsorted(back, p[0] + self.zones.break_mm, "left")) - 1, 0)
        lead = K.transport_map(np.ascontiguousarray(self._S[r:]), self.zones.array(), p)
        ok = int(np.argmax(~np.isfinite(lead))) if not np.all(np.isfinite(lead)) else lead.size
        self._lead[self._n_lead - self._f0 : self._n_lead - self._f0 + ok] = lead[:ok]
        self._n_lead += ok

    def _run_kernel(self, a: int, b: int, stop: int) -> None:
        """Draw and deposit the fibres whose leading ends are fed up to grid point ``stop``."""
        s_off = self._bin0 * self.h
        lead = self._lead[a - self._f0 : b - self._f0] - s_off
        need = int(math.ceil((lead[-1] + self._longest) / self.h)) + 4
        if need > self._diff.size:
            self._diff = np.concatenate([self._diff, np.zeros(need - self._diff.size)])
        state = self._state.copy()
        state[1] = 0.0
        feed = np.array([self._p0 + FED_STEP_MM * a, FED_STEP_MM, self.scale,
                         self._p0 + FED_STEP_MM * stop, 0.0])  # fmt: skip
        K.draft_random(self._rng_fibres, lead, self._quantiles,
                       np.ascontiguousarray(self._cum[a - self._f0 : b - self._f0]), feed,
                       np.empty(0), self.h, self._diff, np.zeros((0, 3)), state)  # fmt: skip
        if state[K.STATE.index("done")]:
            raise RuntimeError("the streamed drafting ran past its transport map")
        self._k = a + int(state[1])
        state[1] = 0.0
        self._state = state

    def _complete(self) -> StreamPiece:
        """The bins no fibre can reach any more, read by the sensors; then drop what is done."""
        lead_k = self._lead[self._k - self._f0] if self._k < self._n_lead else math.nan
        # a fibre to come lands at lead_k or later; a bin below it is complete (one bin's
        # margin for the rounding of the window's offset)
        n_final = int(math.floor(lead_k / self.h)) - 1 if math.isfinite(lead_k) else self._bin0
        n = max(n_final - self._bin0, 0)
        if n > self._diff.size - 2:
            n = self._diff.size - 2
        tex = np.cumsum(np.concatenate([[self._carry], self._diff[:n]]))[1:]
        start_m = self._bin0 * self.h * 1e-3
        if n:
            self._carry = float(tex[-1])
            self._diff = self._diff[n:]
            self._bin0 += n
        ktex = tex / 1000.0
        self.bins += n
        self._sum += float(ktex.sum())
        self._sum2 += float(np.dot(ktex, ktex))
        s, x, t, infeed, fed = self._read(ktex, self._bin0 - n)
        self._drop()
        return StreamPiece(s, x, t, infeed, fed, start_m, ktex)

    def _read(self, ktex: np.ndarray, first: int) -> tuple[np.ndarray, ...]:
        """The delivery sensor's readings of new true bins ``first ...`` (SliverSensor.read,
        continued), the infeed reading held and the store's clock at their times."""
        d = self.delivery
        box = np.concatenate([self._box_tail, ktex])
        c = np.concatenate([[0.0], np.cumsum(box)])
        n_tail = self._box_tail.size
        idx = np.arange(n_tail + 1, box.size + 1)
        lo = np.maximum(idx - self._box_w, 0)
        x = (c[idx] - c[lo]) / (idx - lo)
        self._box_tail = box[-(self._box_w - 1) :] if self._box_w > 1 else np.empty(0)
        if d.lag_mm > 0 and x.size:
            a = math.exp(-self.h / d.lag_mm)
            prev = x[0] if self._lag_y is None else self._lag_y
            x = lfilter([1 - a], [1.0, -a], x, zi=[a * prev])[0]
            self._lag_y = float(x[-1])
        bins = first + np.arange(ktex.size)
        keep = (bins + 1) % self._read_every == 0
        s_mm = (bins[keep] + 0.5) * self.h
        x = x[keep] * (1.0 + d.gain_error)
        x = x * (1.0 + d.noise * self._rng_delivery.standard_normal(x.size))
        t = np.interp(s_mm, self._S[:, K.FRONT], self._S_t)
        back = np.interp(t, self._S_t, self._S[:, K.BACK])
        k = np.floor((back + self.infeed.scan_ahead_mm - self._q0) / self._pitch).astype(np.int64)
        held = self._reads[np.clip(k - self._r0, 0, max(self._reads.size - 1, 0))]
        back0 = 0.0 if self._back0 is None else self._back0
        return (s_mm * 1e-3, x, t + self.t0, held * self.feed.total_ktex,
                (back - back0) * 1e-3)  # fmt: skip

    def _drop(self) -> None:
        """Forget rows, fed points and readings nothing needs any more."""
        s_next = (self._bin0 + 0.5) * self.h
        r_bins = int(np.searchsorted(self._S[:, K.FRONT], s_next, "right")) - 2
        p_next = self._p0 + FED_STEP_MM * self._n_lead
        r_feed = int(np.searchsorted(self._S[:, K.BACK], p_next + self.zones.break_mm, "right")) - 2
        r = max(min(r_bins, r_feed), 0)
        if r > 1000:
            self._S, self._S_t = self._S[r:], self._S_t[r:]
        # readings: the store reaches back `action point - scan ahead`, the delivery's infeed
        # reading to the back roller's place when the oldest bin to come passed the front nip
        back_old = float(self._S[0, K.BACK])
        behind = self.infeed.scan_ahead_mm - max(self.action_point_mm or 0.0, 0.0)
        q_keep = back_old + min(behind, self.infeed.scan_ahead_mm) - 2 * self._pitch
        k_keep = int(math.floor((q_keep - self._q0) / self._pitch)) - self._r0
        if k_keep > 10_000:
            self._reads, self._r0 = self._reads[k_keep:], self._r0 + k_keep
        f_keep = (
            min(self._k, self._n_lead, self._m0 + self._mass.size - self._kernel.size) - self._f0
        )
        if f_keep > 100_000:
            self._rel, self._cum, self._lead = (a[f_keep:] for a in (self._rel, self._cum,
                                                                     self._lead))  # fmt: skip
            self._f0 += f_keep
        q_next = self._q0 + self._pitch * (self._r0 + self._reads.size)
        m_keep = int(math.floor((q_next - self._p0) / FED_STEP_MM)) - self._width - 4 - self._m0
        if m_keep > 100_000:
            self._mass, self._m0 = self._mass[m_keep:], self._m0 + m_keep

    # ---- figures -------------------------------------------------------------------------
    @property
    def delivered_m(self) -> float:
        """True sliver completed, m."""
        return self.bins * self.h * 1e-3

    def true_evenness(self) -> tuple[float, float]:
        """Count (ktex) and CV (%) of the true sliver completed so far."""
        if self.bins < 2:
            return math.nan, math.nan
        mean = self._sum / self.bins
        var = max(self._sum2 / self.bins - mean * mean, 0.0)
        return mean, 100.0 * math.sqrt(var) / mean


__all__ = ["StreamDrafting", "StreamPiece"]
