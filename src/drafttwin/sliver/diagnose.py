"""The sliver's diagnosis: evenness, spectrogram, chimneys and the elements behind them.

:func:`diagnose_sliver` takes a sliver record (mass per length) or an evenness tester's
spectrogram, the drive train and the fibres, and returns a :class:`SliverDiagnosis`. For a
record, each chimney is located at the periodogram's peak within its channel (resolution
``lambda / L``), so elements are matched on their wavelength within
``max(lambda / L, 1 %)`` (1 %: the running point's belt creep and speed), not on the
channel (7 % wide); a tester's table has only its channels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drafttwin.mechanics import DriveTrain
from drafttwin.sliver.attribute import (
    HARMONICS,
    Candidate,
    ChimneyCause,
    attribute,
    ranked_elements,
)
from drafttwin.sliver.drafting import DraftingZones
from drafttwin.sliver.evenness import Evenness, evenness
from drafttwin.sliver.record import Sliver
from drafttwin.sliver.spectrogram import Spectrogram, spectrogram
from drafttwin.sliver.staple import StapleDiagram
from drafttwin.sliver.transfer import fibre_length_gain, roller_gains, transit_lengths_m
from drafttwin.sliver.wavelengths import Element, WavelengthTable, wavelength_table

SPEED_TOLERANCE = 0.01


@dataclass(frozen=True)
class SliverDiagnosis:
    """What the sliver says: evenness (None for a tester's table), the spectrogram, each
    chimney with its ranked causes, and the wavelength table used."""

    evenness: Evenness | None
    spectrogram: Spectrogram
    causes: list[ChimneyCause]
    table: WavelengthTable
    drafts: dict[str, float]
    known: list[ChimneyCause] = field(default_factory=list)
    """Chimneys already in the machine's healthy reference (its own lines), not new."""

    @property
    def elements(self) -> list[str]:
        """Elements in order of their best placement over all chimneys."""
        return ranked_elements(self.causes)

    def to_dict(self) -> dict[str, Any]:
        return {
            "evenness": None if self.evenness is None else self.evenness.to_dict(),
            "chimneys": [c.to_dict() for c in self.causes],
            "known_lines": [c.to_dict() for c in self.known],
            "elements": self.elements,
            "drafts": self.drafts,
            "spectrogram": self.spectrogram.to_frame().to_dict(orient="list"),
            "wavelength_table": self.table.to_dict(),
        }


def running_drafts(table: WavelengthTable, train: DriveTrain) -> dict[str, float]:
    """Zone drafts at the table's running point (roller surface speeds)."""
    v = {}
    for r in train.spec.roller:
        e = next(x for x in table.elements if x.name == f"roller {r.name}")
        v[r.name] = e.frequency_hz * math.pi * r.diameter_mm
    return {"total": v["front"] / v["back"], "main": v["front"] / v["second"],
            "middle": v["second"] / v["third"], "break": v["third"] / v["back"]}  # fmt: skip


def diagnose_sliver(record: Sliver | Spectrogram, train: DriveTrain, staple: StapleDiagram,
                    zones: DraftingZones | None = None, *, sensor_length_m: float = 0.0,
                    harmonics: int = HARMONICS, table: WavelengthTable | None = None,
                    reference: Sliver | None = None) -> SliverDiagnosis:  # fmt: skip
    """Evenness, spectrogram and the chimneys' causes of a sliver record or a tester's
    spectrogram, for the drive train ``train`` at its running point. ``reference``: a
    healthy sliver of the same machine; a chimney no higher there than the chimney rule
    allows (amplitude at most 1.5 x the reference's in that channel) is one of the machine's
    own lines (``known``), not a new one."""
    zones = zones or DraftingZones()
    table = table or wavelength_table(train, harmonics=harmonics)
    drafts = running_drafts(table, train)
    ev = None
    if isinstance(record, Sliver):
        ev = evenness(record.linear_density_ktex, record.step_m, staple, record.fibre_scale)
        spec = spectrogram(record.linear_density_ktex, record.step_m, staple,
                           fibre_scale=record.fibre_scale, sensor_length_m=sensor_length_m)  # fmt: skip
        chimneys = _with_peaks(spec.chimneys(), record)
    else:
        spec, chimneys = record, record.chimneys()
    gauges = (zones.main_mm, zones.middle_mm, zones.break_mm)
    causes = attribute(chimneys, table, gauges, drafts, staple, harmonics)
    known: list[ChimneyCause] = []
    if reference is not None:
        ref = spectrogram(reference.linear_density_ktex, reference.step_m, staple,
                          fibre_scale=reference.fibre_scale, sensor_length_m=sensor_length_m)  # fmt: skip
        known = [c for c in causes if not _above_reference(c, ref)]
        causes = [c for c in causes if _above_reference(c, ref)]
    return SliverDiagnosis(ev, spec, causes, table, drafts, known)


def _above_reference(cause: ChimneyCause, ref: Spectrogram) -> bool:
    """The chimney rule against the reference: above 1.5 x the reference's channel."""
    lam = float(cause.extra.get("channel_m", cause.wavelength_m))
    j = int(np.argmin(np.abs(np.log(ref.wavelength_m / lam)))) if ref.wavelength_m.size else -1
    if j < 0 or abs(math.log(ref.wavelength_m[j] / lam)) > 0.04:
        return True  # the reference does not reach this wavelength
    return cause.amplitude_pct > 1.5 * float(ref.amplitude_pct[j])


def _refined_frequency(x: np.ndarray, step_m: float, f0: float, df: float) -> float:
    """The spatial frequency (1/m) within one bin of ``f0`` where the record's Fourier sum is
    largest (a line between two bins), to 1/40 of a bin: a line fitted at it stays coherent
    over the whole record."""
    s = np.arange(x.size) * step_m
    grid = f0 + df * np.linspace(-1.0, 1.0, 81)
    best, best_f = -1.0, f0
    for f in grid:
        a = abs(np.dot(x, np.exp(-2j * np.pi * f * s)))
        if a > best:
            best, best_f = a, float(f)
    return best_f


def _with_peaks(chimneys: list[dict[str, Any]], record: Sliver) -> list[dict[str, Any]]:
    """Each chimney row with ``peak_m`` (the periodogram's largest bin within the channel,
    refined by a parabola through its neighbours) and ``tolerance``."""
    x = record.linear_density_ktex / record.linear_density_ktex.mean() - 1.0
    power = np.abs(np.fft.rfft(x - x.mean())) ** 2
    f = np.fft.rfftfreq(x.size, record.step_m)
    length = x.size * record.step_m
    out = []
    for c in chimneys:
        inside = np.flatnonzero((f >= 1.0 / c["hi_m"]) & (f <= 1.0 / c["lo_m"]))
        if inside.size == 0:
            out.append(c)
            continue
        k = int(inside[np.argmax(power[inside])])
        peak = 1.0 / _refined_frequency(x, record.step_m, k / length, 1.0 / length)
        out.append({**c, "peak_m": peak,
                    "tolerance": max(peak / length, SPEED_TOLERANCE)})  # fmt: skip
    return out


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


def encoder_line_pct(time_s: np.ndarray, rpm: np.ndarray, order: float) -> float:
    """Relative amplitude (%) of the line at ``order`` times the roller's own rotation in its
    interval-mean speeds (one channel; gaps filled, the data path's spikes set aside),
    corrected for the interval averaging; NaN at or above the Nyquist frequency. The fit is
    in the roller's angle (order analysis), so the line stays coherent while the speed
    wanders."""
    x = np.asarray(rpm, np.float64)
    ok = np.isfinite(x)
    if ok.sum() < 100:
        return math.nan
    step = float(np.median(np.diff(time_s)))
    med = float(np.median(x[ok]))
    filled = np.interp(np.arange(x.size), np.flatnonzero(ok), x[ok])
    if not 0 < order * med / 60.0 < 0.45 / step:
        return math.nan
    theta = 2 * math.pi * order * np.cumsum(filled / 60.0 * step)
    keep = ok & (np.abs(x - med) < 0.01 * abs(med))  # spikes are not the line
    t, y, th = time_s[keep], x[keep], theta[keep]
    design = np.column_stack([np.sin(th), np.cos(th), np.ones_like(t), t - t.mean()])
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    fade = np.sinc(order * med / 60.0 * step)
    return float(math.hypot(coef[0], coef[1]) / abs(coef[2]) / fade * 100)


def check_with_encoders(diagnosis: SliverDiagnosis, time_s: np.ndarray,
                        rpm: dict[str, np.ndarray]) -> dict[str, list[EncoderCheck]]:  # fmt: skip
    """For each chimney (keyed by its wavelength in cm), the encoders' word on each plausible
    candidate. A gear, pulley, sprocket or shaft that leaves a chimney turns the rollers it
    drives unevenly at its own frequency; a roller's radius run-out does not show in any
    angular speed. Noise: the RMS of the same fit at eight nearby orders."""
    out: dict[str, list[EncoderCheck]] = {}
    by_name = {e.name: e for e in diagnosis.table.elements}
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
            measured = max(encoder_line_pct(time_s, rpm[r], orders[r]) for r in moved)
            near = [encoder_line_pct(time_s, rpm[r], orders[r] * (1 + d)) for r in moved
                    for d in (-0.06, -0.045, -0.03, -0.02, 0.02, 0.03, 0.045, 0.06)]  # fmt: skip
            noise = _rms(near)
            expected = 0.0 if e.kind == "roller" else c.required_modulation_pct
            seen = _rollers_with_line(time_s, rpm, e, by_name)
            checks.append(EncoderCheck(c.element, expected, measured, noise,
                                       _encoder_verdict(expected, measured, noise),
                                       tuple(r for r in seen if r not in e.rollers
                                             or e.kind == "roller")))  # fmt: skip
        out[f"{cause.wavelength_m * 100:.2f} cm"] = checks
    return out


def _rollers_with_line(time_s: np.ndarray, rpm: dict[str, np.ndarray], e: Element,
                       by_name: dict[str, Element]) -> list[str]:  # fmt: skip
    """Rollers whose angular speed carries the element's line: above three times the noise
    and at least 0.3 of the largest."""
    amp, noise = {}, {}
    for r in rpm:
        ref = by_name.get(f"roller {r}")
        if ref is None:
            continue
        order = e.frequency_hz / ref.frequency_hz
        amp[r] = encoder_line_pct(time_s, rpm[r], order)
        near = [
            encoder_line_pct(time_s, rpm[r], order * (1 + d)) for d in (-0.04, -0.02, 0.02, 0.04)
        ]
        noise[r] = _rms(near)
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

        def rank(c: Candidate, share: float = share, verdicts: dict = verdicts,
                 misfit: dict = misfit) -> tuple:  # fmt: skip
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
    out = {}
    for cause in diagnosis.causes:
        lam = cause.wavelength_m
        c_sl = _line(x, sliver.delivered_length_m, lam)
        f_hz = _front_hz(rpm) * (math.pi * _front_d_mm(diagnosis) * 1e-3) / lam
        fade = float(np.sinc(f_hz * step))
        if not 0 < f_hz < 0.45 / step:
            continue  # above the encoders' Nyquist frequency: they cannot say
        u = np.array([_line(_relative(rpm[r])[inside], s_enc, lam) / fade
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


def _relative(x: np.ndarray) -> np.ndarray:
    """Relative fluctuation of a speed channel, gaps filled, spikes (> 1 %) set aside."""
    x = np.asarray(x, np.float64)
    ok = np.isfinite(x)
    med = float(np.median(x[ok]))
    good = ok & (np.abs(x - med) < 0.01 * abs(med))
    idx = np.arange(x.size)
    filled = np.interp(idx, idx[good], x[good])
    return filled / filled.mean() - 1.0


def _front_hz(rpm: dict[str, np.ndarray]) -> float:
    return float(np.nanmedian(np.asarray(rpm["front"], np.float64))) / 60.0


def _front_d_mm(diagnosis: SliverDiagnosis) -> float:
    e = next(x for x in diagnosis.table.elements if x.name == "roller front")
    return e.wavelength_m / math.pi * 1e3  # the front roller's line is its circumference
