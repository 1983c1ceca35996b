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
from drafttwin.sliver.attribution import (
    HARMONICS,
    ChimneyCause,
    attribute,
    ranked_elements,
)
from drafttwin.sliver.drafting import DraftingZones
from drafttwin.sliver.irregularity import Evenness, evenness
from drafttwin.sliver.record import Sliver
from drafttwin.sliver.reference import SliverReference
from drafttwin.sliver.spectra import Spectrogram, spectrogram
from drafttwin.sliver.staple import StapleDiagram
from drafttwin.sliver.wavelengths import WavelengthTable, wavelength_table

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
                    reference: Sliver | Spectrogram | SliverReference | None = None
                    ) -> SliverDiagnosis:  # fmt: skip
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
        ref = reference_spectrogram(reference, staple, sensor_length_m)
        known = [c for c in causes if not _above_reference(c, ref)]
        causes = [c for c in causes if _above_reference(c, ref)]
    return SliverDiagnosis(ev, spec, causes, table, drafts, known)


def reference_spectrogram(reference: Sliver | Spectrogram | SliverReference, staple: StapleDiagram,
                          sensor_length_m: float = 0.0) -> SliverReference:  # fmt: skip
    """The reference lines of a healthy sliver (a spectrogram or a reference passes as it
    is: a watch computes it once, not at every check)."""
    if isinstance(reference, Spectrogram | SliverReference):
        return SliverReference.of(reference)
    return SliverReference.of(
        spectrogram(
            reference.linear_density_ktex,
            reference.step_m,
            staple,
            fibre_scale=reference.fibre_scale,
            sensor_length_m=sensor_length_m,
        )
    )


def _above_reference(cause: ChimneyCause, ref: SliverReference) -> bool:
    """The chimney rule against the reference (:meth:`SliverReference.holds`)."""
    channels = cause.extra.get("channels_m") or [cause.extra.get("channel_m", cause.wavelength_m)]
    return not ref.holds(cause.amplitude_pct, [float(c) for c in channels])


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
    return _one_row_per_line(out)


def _one_row_per_line(chimneys: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Chimneys of adjacent channels whose peaks are one line (within the matching
    tolerance) as one row: a line near a band edge leaks into both channels. The row keeps
    the larger channel's wavelength and the union of both bands: amplitude and base add in
    quadrature (band variances add), so the line's excess over the base is kept whole;
    ``channels_m`` lists the channels it covers."""
    out: list[dict[str, Any]] = []
    for c in sorted(chimneys, key=lambda r: float(r["wavelength_m"])):
        prev = out[-1] if out else None
        if prev is not None and "peak_m" in c and "peak_m" in prev and _adjacent(prev, c):
            tol = max(float(prev["tolerance"]), float(c["tolerance"]))
            if abs(math.log(float(c["peak_m"]) / float(prev["peak_m"]))) <= math.log1p(tol):
                main = prev if prev["amplitude_pct"] >= c["amplitude_pct"] else c
                out[-1] = {**main,
                           "amplitude_pct": math.hypot(prev["amplitude_pct"], c["amplitude_pct"]),
                           "base_pct": math.hypot(prev["base_pct"], c["base_pct"]),
                           "lo_m": prev["lo_m"], "hi_m": c["hi_m"],
                           "channels_m": [*prev.get("channels_m", [prev["wavelength_m"]]),
                                          c["wavelength_m"]]}  # fmt: skip
                continue
        out.append(c)
    return out


def _adjacent(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """Channel ``b`` follows channel ``a`` (their bands touch)."""
    return math.isclose(float(a["hi_m"]), float(b["lo_m"]), rel_tol=1e-9)
