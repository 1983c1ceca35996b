"""The roller encoders' word on a chimney: the sliver sees surface speed, the encoders
angular speed.

* :func:`drive_share`: how much of a chimney the rollers' measured angular speeds explain,
  through the drafting transfer, in amplitude and phase (the rest is the rollers' surfaces
  themselves: radius run-out, a damaged flute);
* :func:`check_with_encoders`: for each look-alike, the line it would need in the encoders,
  the line they carry, and which rollers carry it;
* :func:`rerank` and :func:`with_encoders`: the look-alikes in the encoders' order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drafttwin.data.gaps import interpolate_missing
from drafttwin.sliver.attribution import Candidate, ChimneyCause
from drafttwin.sliver.diagnose import SliverDiagnosis
from drafttwin.sliver.drafting import DraftingZones
from drafttwin.sliver.record import Sliver
from drafttwin.sliver.staple import StapleDiagram
from drafttwin.sliver.transfer import fibre_length_gain, roller_gains, transit_lengths_m
from drafttwin.sliver.wavelengths import Element


@dataclass(frozen=True)
class EncoderCheck:
    """What the roller encoders say of one candidate: its expected once-per-revolution line
    in the angular speeds of the rollers it moves (relative, %), the measured line, the
    noise level there, and a verdict: ``confirmed`` / ``ruled out`` / ``not visible``."""

    element: str
    expected_pct: float
    measured_pct: float
    noise_pct: float
    verdict: str
    unexplained: tuple[str, ...] = ()  # rollers with the line that the element does not move


@dataclass(frozen=True)
class _Channel:
    """One roller's interval-mean speeds made ready once for many line fits: gaps filled,
    the data path's spikes (beyond 1 % of the median) marked, and the roller's angle."""

    time_s: np.ndarray
    filled: np.ndarray  # gaps filled (the angle is counted from these)
    good: np.ndarray  # finite and within the spike band: the samples a fit uses
    median: float
    step_s: float
    revs: np.ndarray  # revolutions turned at each sample's end

    @classmethod
    def of(cls, time_s: np.ndarray, rpm: np.ndarray, min_samples: int = 100) -> _Channel | None:
        x = np.asarray(rpm, np.float64)
        ok = np.isfinite(x)
        if ok.sum() < min_samples:
            return None
        step = float(np.median(np.diff(time_s)))
        med = float(np.median(x[ok]))
        filled = interpolate_missing(x)[0]
        good = ok & (np.abs(x - med) < 0.01 * abs(med))  # spikes are not the line
        return cls(time_s, filled, good, med, step, np.cumsum(filled / 60.0 * step))

    def line_pct(self, order: float) -> float:
        """Relative amplitude (%) of the line at ``order`` times the roller's rotation."""
        f_hz = order * self.median / 60.0
        if not 0 < f_hz < 0.45 / self.step_s:
            return math.nan
        th = 2 * math.pi * order * self.revs[self.good]
        t = self.time_s[self.good]
        design = np.column_stack([np.sin(th), np.cos(th), np.ones_like(t), t - t.mean()])
        coef, *_ = np.linalg.lstsq(design, self.filled[self.good], rcond=None)
        return float(math.hypot(coef[0], coef[1]) / abs(coef[2]) / np.sinc(f_hz * self.step_s)
                     * 100)  # fmt: skip

    def relative(self) -> np.ndarray:
        """Relative fluctuation, spikes bridged like gaps."""
        idx = np.arange(self.filled.size)
        clean = np.interp(idx, idx[self.good], self.filled[self.good])
        relative: np.ndarray = clean / clean.mean() - 1.0
        return relative


class _Lines:
    """Line fits of every roller channel, each channel prepared once and each (roller, order)
    fitted once: the look-alikes of a chimney share their orders."""

    def __init__(self, time_s: np.ndarray, rpm: dict[str, np.ndarray]) -> None:
        self.channels = {r: _Channel.of(time_s, x) for r, x in rpm.items()}
        self._done: dict[tuple[str, float], float] = {}

    def pct(self, roller: str, order: float) -> float:
        key = (roller, order)
        if key not in self._done:
            ch = self.channels.get(roller)
            self._done[key] = math.nan if ch is None else ch.line_pct(order)
        return self._done[key]


def check_with_encoders(diagnosis: SliverDiagnosis, time_s: np.ndarray,
                        rpm: dict[str, np.ndarray]) -> dict[str, list[EncoderCheck]]:  # fmt: skip
    """For each chimney (keyed by its wavelength in cm), the encoders' word on each plausible
    candidate. A gear, pulley, sprocket or shaft that leaves a chimney turns the rollers it
    drives unevenly at its own frequency; a roller's radius run-out does not show in any
    angular speed. Noise: the RMS of the same fit at eight nearby orders."""
    out: dict[str, list[EncoderCheck]] = {}
    by_name = {e.name: e for e in diagnosis.table.elements}
    lines = _Lines(time_s, rpm)
    for cause in diagnosis.causes:
        checks = []
        for c in cause.candidates:
            e = by_name.get(c.element)
            if e is None or not c.plausible:
                continue
            moved = [r for r in e.rollers if r in rpm and f"roller {r}" in by_name]
            if not moved:
                continue
            orders = {r: e.frequency_hz / by_name[f"roller {r}"].frequency_hz for r in moved}
            measured = max(lines.pct(r, orders[r]) for r in moved)
            near = [lines.pct(r, orders[r] * (1 + d)) for r in moved
                    for d in (-0.06, -0.045, -0.03, -0.02, 0.02, 0.03, 0.045, 0.06)]  # fmt: skip
            noise = _rms(near)
            expected = 0.0 if e.kind == "roller" else c.required_modulation_pct
            seen = _rollers_with_line(lines, e, by_name)
            checks.append(EncoderCheck(c.element, expected, measured, noise,
                                       _encoder_verdict(expected, measured, noise),
                                       tuple(r for r in seen if r not in e.rollers
                                             or e.kind == "roller")))  # fmt: skip
        out[f"{cause.wavelength_m * 100:.2f} cm"] = checks
    return out


def _rollers_with_line(lines: _Lines, e: Element, by_name: dict[str, Element]) -> list[str]:
    """Rollers whose angular speed carries the element's line: above three times the noise
    and at least 0.3 of the largest."""
    amp, noise = {}, {}
    for r in lines.channels:
        ref = by_name.get(f"roller {r}")
        if ref is None:
            continue
        order = e.frequency_hz / ref.frequency_hz
        amp[r] = lines.pct(r, order)
        noise[r] = _rms([lines.pct(r, order * (1 + d)) for d in (-0.04, -0.02, 0.02, 0.04)])
    ok = {r: a for r, a in amp.items() if math.isfinite(a) and a > 3 * noise[r]}
    top = max(ok.values(), default=0.0)
    return [r for r, a in ok.items() if a >= 0.3 * top]


def _rms(values: list[float]) -> float:
    """RMS of the finite values (NaN if none: above the encoders' Nyquist frequency)."""
    finite = [v for v in values if math.isfinite(v)]
    return float(np.sqrt(np.mean(np.square(finite)))) if finite else math.nan


def _encoder_verdict(expected: float, measured: float, noise: float) -> str:
    if not (math.isfinite(measured) and math.isfinite(noise)):
        return "not visible (above the encoders' Nyquist frequency)"
    seen = measured > 3 * noise
    if expected == 0.0:
        return "consistent (a radius run-out moves no angular speed)" if not seen else (
            "an angular line is present: an element on the roller's drive fits better")  # fmt: skip
    if expected < 3 * noise:
        return "not visible (expected line below the encoders' noise)"
    if measured >= 0.5 * expected:
        return "confirmed by the encoders"
    return "ruled out: the encoders do not see the line it would need"


def rerank(diagnosis: SliverDiagnosis, checks: dict[str, list[EncoderCheck]],
           shares: dict[str, float]) -> SliverDiagnosis:  # fmt: skip
    """Re-rank each chimney's look-alikes with the encoders: where they explain little of
    the chimney (share < 0.3) a roller's own surface comes first; where they explain most of
    it (> 0.6) the drive elements come first, those whose moved rollers match the rollers
    that carry the line and that the encoders confirm ahead; in between the sliver's own
    order stands."""
    order = {"confirmed": 0, "consistent": 1, "not": 1, "an": 2, "ruled": 3}
    causes = []
    for cause in diagnosis.causes:
        key = f"{cause.wavelength_m * 100:.2f} cm"
        verdicts = {k.element: k.verdict.split()[0] for k in checks.get(key, [])}
        misfit = {k.element: len(k.unexplained) for k in checks.get(key, [])}
        share = shares.get(key, math.nan)

        def rank(c: Candidate, share: float = share, verdicts: dict[str, str] = verdicts,
                 misfit: dict[str, int] = misfit) -> tuple[bool | int, ...]:  # fmt: skip
            if not math.isfinite(share) or 0.3 <= share <= 0.6:
                return (not c.plausible,)  # undecided: the sliver's own order stands
            if share < 0.3:
                return (not c.plausible, c.kind != "roller")
            return (
                not c.plausible,
                c.kind == "roller",
                misfit.get(c.element, 0),
                order.get(verdicts.get(c.element, "not"), 1),
            )

        ranked = sorted(cause.candidates, key=rank)
        verdict = cause.verdict
        if math.isfinite(share):
            verdict += f"; the roller encoders explain {share:.0%} of it"
            if ranked and cause.candidates and ranked[0].element != cause.candidates[0].element:
                verdict = f"{ranked[0].element} with the encoders' evidence; " + verdict
        causes.append(ChimneyCause(cause.wavelength_m, cause.amplitude_pct, cause.base_pct,
                                   cause.excess_pct, tuple(ranked), verdict,
                                   cause.fed_wavelength_m,
                                   {**cause.extra, "encoder_share": share,
                                    "encoders": [vars(k) for k in checks.get(key, [])]}))  # fmt: skip
    return SliverDiagnosis(diagnosis.evenness, diagnosis.spectrogram, causes, diagnosis.table,
                           diagnosis.drafts, diagnosis.known)  # fmt: skip


def with_encoders(diagnosis: SliverDiagnosis, sliver: Sliver, time_s: np.ndarray,
                  rpm: dict[str, np.ndarray], staple: StapleDiagram,
                  zones: DraftingZones | None = None) -> SliverDiagnosis:  # fmt: skip
    """The sliver's diagnosis with the roller encoders' evidence (:func:`drive_share`,
    :func:`check_with_encoders`, :func:`rerank`)."""
    if not diagnosis.causes:
        return diagnosis
    shares = drive_share(diagnosis, sliver, time_s, rpm, staple, zones)
    return rerank(diagnosis, check_with_encoders(diagnosis, time_s, rpm), shares)


def drive_share(diagnosis: SliverDiagnosis, sliver: Sliver, time_s: np.ndarray,
                rpm: dict[str, np.ndarray], staple: StapleDiagram,
                zones: DraftingZones | None = None) -> dict[str, float]:  # fmt: skip
    """For each chimney (keyed by its wavelength in cm), the share of it (0-1) that the
    rollers' measured angular speeds explain in phase (the projection of the predicted line on
    the sliver's, over the sliver's power): each roller's line at the chimney's order is
    fitted in the encoders' speeds (phase taken from the sliver's own delivered length at the
    encoders' times, so both share one reference), carried through the drafting transfer
    (:func:`drafttwin.sliver.transfer.roller_gains`, the fibre-length filter) and compared
    with the sliver's line, amplitude and phase. What they do not explain comes from the
    rollers' surfaces themselves (radius run-out, a damaged flute): the encoders are blind
    to it, the sliver is not. Needs the sliver's ``time`` on the encoders' clock."""
    if sliver.time_s is None:
        return {}
    zones = zones or DraftingZones()
    step = float(np.median(np.diff(time_s)))
    mid = time_s - step / 2  # an interval mean stands for its interval's middle
    inside = (mid >= sliver.time_s[0]) & (mid <= sliver.time_s[-1])
    s_enc = np.interp(mid[inside], sliver.time_s, sliver.delivered_length_m)
    x = sliver.linear_density_ktex / sliver.linear_density_ktex.mean() - 1.0
    gauges = (zones.main_mm, zones.middle_mm, zones.break_mm)
    transit = transit_lengths_m(gauges, diagnosis.drafts)
    relative = {r: _relative(time_s, rpm[r]) for r in ("front", "second", "third", "back")}
    out = {}
    for cause in diagnosis.causes:
        lam = cause.wavelength_m
        c_sl = _line(x, sliver.delivered_length_m, lam)
        f_hz = _front_hz(rpm) * (math.pi * _front_d_mm(diagnosis) * 1e-3) / lam
        fade = float(np.sinc(f_hz * step))
        if not 0 < f_hz < 0.45 / step:
            continue  # above the encoders' Nyquist frequency: they cannot say
        u = np.array([_line(relative[r][inside], s_enc, lam) / fade
                      for r in ("front", "second", "third", "back")])  # fmt: skip
        gains = roller_gains(lam, transit)[0]
        c_pr = complex(np.dot(gains, u)) * complex(fibre_length_gain(staple, lam)[0])
        share = (c_pr * c_sl.conjugate()).real / abs(c_sl) ** 2  # the in-phase part explained
        out[f"{lam * 100:.2f} cm"] = float(min(1.0, max(0.0, share)))
    return out


def _line(x: np.ndarray, s: np.ndarray, lam: float) -> complex:
    """``C`` with ``x ~ Re(C exp(i 2 pi s / lam))`` by least squares (with a mean)."""
    k = 2 * math.pi / lam
    design = np.column_stack([np.cos(k * s), -np.sin(k * s), np.ones_like(s)])
    coef, *_ = np.linalg.lstsq(design, x, rcond=None)
    return complex(coef[0], coef[1])


def _relative(time_s: np.ndarray, rpm: np.ndarray) -> np.ndarray:
    """Relative fluctuation of a speed channel, gaps and spikes (> 1 %) bridged."""
    channel = _Channel.of(time_s, rpm, min_samples=1)
    assert channel is not None
    return channel.relative()


def _front_hz(rpm: dict[str, np.ndarray]) -> float:
    return float(np.nanmedian(np.asarray(rpm["front"], np.float64))) / 60.0


def _front_d_mm(diagnosis: SliverDiagnosis) -> float:
    e = next(x for x in diagnosis.table.elements if x.name == "roller front")
    return e.wavelength_m / math.pi * 1e3  # the front roller's line is its circumference
