"""Chimney to element: which rotating element explains each chimney of a spectrogram.

For every chimney the wavelength table (:mod:`drafttwin.sliver.wavelengths`) is searched for
elements whose line or harmonic falls within the channel (its band widened by a quarter
channel each side for the running point's uncertainty). Each candidate is scored by:

* the drafting transfer (:mod:`drafttwin.sliver.transfer`): an element can leave a chimney
  only through the rollers it moves; what relative speed modulation (%) would it need for the
  chimney's excess over the base? An element whose gain at that wavelength is below
  :data:`MIN_GAIN` (e.g. the motor, which moves every roller alike) cannot explain it;
* the harmonic order (the fundamental first) and the other chimneys at its harmonics (a
  non-sinusoidal defect such as a damaged flute leaves a comb);
* the distance from the channel's centre.

Elements whose lines fall within one channel of each other cannot be told apart by the
sliver (e.g. the front roller and the gears on its drive shaft): they are named as
look-alikes. A chimney that no drive element explains comes from the feed: its wavelength
divided by the total draft is where the defect sits on the fed sliver.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

from drafttwin.sliver.staple import StapleDiagram
from drafttwin.sliver.transfer import mass_gain
from drafttwin.sliver.wavelengths import Element, WavelengthTable

__all__ = ["Candidate", "ChimneyCause", "Element", "attribute", "ranked_elements", "runout_um"]

HARMONICS = 8
"""Harmonics of each element matched: a damaged flute's comb reaches the 7th and 8th (2 cm
on the front roller) before the fibre lengths bury it."""
MIN_GAIN = 0.05
"""Below this |gain| from speed to mass an element cannot make a visible chimney."""
TOLERANCE_OCTAVES = 1 / 20 + 1 / 40
"""A line counts as in a channel within half a channel plus a quarter channel."""


@dataclass(frozen=True)
class Candidate:
    """One element that may explain a chimney."""

    element: str
    kind: str
    harmonic: int
    wavelength_m: float
    gain: float  # |speed-to-mass gain| at the chimney's wavelength
    required_modulation_pct: float  # speed modulation the element would need (inf: cannot)
    plausible: bool
    harmonics_seen: int  # chimneys at this element's other harmonics
    lookalikes: tuple[str, ...] = ()
    offset: float = 0.0  # |ln(line / chimney)| over the matching tolerance (0 = on it)


@dataclass(frozen=True)
class ChimneyCause:
    """A chimney and its ranked causes."""

    wavelength_m: float
    amplitude_pct: float
    base_pct: float
    excess_pct: float
    candidates: tuple[Candidate, ...]
    verdict: str
    fed_wavelength_m: float = math.nan
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def attribute(chimneys: list[dict[str, Any]], table: WavelengthTable,
              gauges_mm: tuple[float, float, float], drafts: dict[str, float],
              staple: StapleDiagram, harmonics: int = HARMONICS) -> list[ChimneyCause]:  # fmt: skip
    """Rank the elements behind each chimney (rows with ``wavelength_m``, ``amplitude_pct``,
    ``base_pct``, as :meth:`Spectrogram.chimneys` gives them). A row with ``peak_m`` (the
    periodogram's peak within the channel) and ``tolerance`` (relative) is matched on that
    wavelength within that tolerance, not on the channel."""
    waves = [float(c.get("peak_m", c["wavelength_m"])) for c in chimneys]
    out = []
    for c in chimneys:
        lam, amp, base = float(c["wavelength_m"]), float(c["amplitude_pct"]), float(c["base_pct"])
        at = float(c.get("peak_m", lam))
        tol = float(c.get("tolerance", 2.0**TOLERANCE_OCTAVES - 1.0))
        excess = math.sqrt(max(amp**2 - base**2, 0.0))
        cands = [_candidate(e, h, at, excess, table, gauges_mm, drafts, staple, waves,
                            harmonics, tol) for e, h in table.near(at, tol, harmonics)]  # fmt: skip
        cands = _with_lookalikes(sorted(cands, key=_rank))
        also = _same_channel(lam, {c.element for c in cands}, table, gauges_mm, drafts, staple)
        verdict = _verdict(cands, at, drafts) + _also_text(also)
        out.append(ChimneyCause(at, amp, base, excess, tuple(cands), verdict,
                                at / drafts["total"],
                                {"channel_m": lam, "tolerance": tol,
                                 "same_channel": [n for n, _ in also],
                                 **({"channels_m": list(c["channels_m"])}
                                    if "channels_m" in c else {})}))  # fmt: skip
    return out


SAME_CHANNEL_MAX = 3
"""Other elements named as lying in a chimney's channel (the nearest kinds first)."""


def _same_channel(channel_m: float, named: set[str], table: WavelengthTable,
                  gauges_mm: tuple[float, float, float], drafts: dict[str, float],
                  staple: StapleDiagram) -> list[tuple[str, float]]:  # fmt: skip
    """Elements whose fundamental lies in the channel (10 per octave) but too far from the
    chimney's peak to explain it, and that could make a line there: two lines in one channel
    (the second and third rollers lie 2 % apart, the channel is 7 % wide) are both in its
    amplitude, and a window of another length may peak on the other."""
    found = []
    for e, h in table.near(channel_m, 2 ** (1 / 20) - 1, 1):
        if e.name in named or h != 1:
            continue
        if _gain(e, e.wavelength_m, gauges_mm, drafts, staple) >= MIN_GAIN:
            found.append((_prior(e.kind), e.name, e.wavelength_m))
    return [(n, w) for _, n, w in sorted(found)[:SAME_CHANNEL_MAX]]


def _gain(e: Element, lam: float, gauges_mm: tuple[float, float, float],
          drafts: dict[str, float], staple: StapleDiagram) -> float:  # fmt: skip
    """|speed-to-mass gain| at ``lam`` of the rollers ``e`` moves (a roller only itself)."""
    moved = {e.rollers[0]: 1.0} if e.kind == "roller" else {r: 1.0 for r in e.rollers}
    return float(abs(mass_gain(moved, lam, gauges_mm, drafts, staple)[0]))


def _prior(kind: str) -> int:
    """Place of an element's kind in :data:`KIND_PRIOR` (unknown kinds last)."""
    return KIND_PRIOR.index(kind) if kind in KIND_PRIOR else len(KIND_PRIOR)


def _also_text(also: list[tuple[str, float]]) -> str:
    """The verdict's tail: "; the channel also holds the line at 60.2 cm (roller third,
    gear J (I-J))"."""
    lines: dict[str, list[str]] = {}
    for name, w in also:
        lines.setdefault(_fmt_m(w), []).append(name)
    return "".join(f"; the channel also holds the line at {w} ({', '.join(names)})"
                   for w, names in lines.items())  # fmt: skip


def _candidate(e: Element, h: int, lam: float, excess: float, table: WavelengthTable,
               gauges_mm: tuple[float, float, float], drafts: dict[str, float],
               staple: StapleDiagram, waves: list[float], harmonics: int,
               tol: float) -> Candidate:  # fmt: skip
    gain = _gain(e, lam, gauges_mm, drafts, staple)
    plausible = gain >= MIN_GAIN
    required = excess / gain if plausible else math.inf
    seen = sum(1 for k in e.orders(harmonics) if k != h and any(
        abs(math.log(e.wavelength_m / k / w)) <= math.log1p(tol) for w in waves))  # fmt: skip
    offset = abs(math.log(e.wavelength_m / h / lam)) / math.log1p(tol)
    return Candidate(e.name, e.kind, h, e.wavelength_m / h, gain, required, plausible, seen,
                     offset=offset)  # fmt: skip


KIND_PRIOR = ("roller", "gear", "sprocket", "pulley", "chain", "belt", "mesh", "rattle", "shaft",
              "motor")  # fmt: skip
"""At equal evidence the kind of element more often behind such a chimney in practice comes
first: an eccentric or damaged roller, then the gears on its shaft; the others stay named as
look-alikes. The modulation an element would need only rules it in or out: real defects
differ by more than the gains do."""


def _rank(c: Candidate) -> tuple[bool, int, int, int, int, float]:
    # plausible first; a comb of harmonics; the fundamental; the line nearest the chimney (in
    # halves of the tolerance: equal lines tie); the prior of the kind; the smallest
    # speed modulation needed
    near = math.floor(2 * c.offset)
    return (not c.plausible, -c.harmonics_seen, c.harmonic, near, _prior(c.kind),
            c.required_modulation_pct)  # fmt: skip


def _with_lookalikes(cands: list[Candidate]) -> list[Candidate]:
    """Name, for each candidate, the others whose line lies within a quarter channel."""
    out = []
    for c in cands:
        twins = tuple(o.element for o in cands if o is not c and o.plausible == c.plausible
                      and abs(math.log2(o.wavelength_m / c.wavelength_m)) <= 1 / 40)  # fmt: skip
        out.append(Candidate(**{**asdict(c), "lookalikes": twins}))
    return out


def _verdict(cands: list[Candidate], lam: float, drafts: dict[str, float]) -> str:
    plausible = [c for c in cands if c.plausible]
    if not plausible:
        fed = lam / drafts["total"]
        why = " (the elements at this wavelength move every roller alike)" if cands else ""
        return (
            f"no drive element explains it{why}: from the feed, a defect at "
            f"{_fmt_m(fed)} on the fed sliver"
        )
    top = plausible[0]
    same = [top.element, *top.lookalikes]
    runout = _runout_text(top, drafts)
    if len(same) > 1:
        return (
            f"{top.element} (harmonic {top.harmonic}) or its look-alikes "
            f"{', '.join(top.lookalikes)}: one wavelength, the sliver cannot tell them apart"
            + runout
        )
    return (f"{top.element} (harmonic {top.harmonic}), about "
            f"{top.required_modulation_pct:.2g} % speed modulation{runout}")  # fmt: skip


DRAFT_TO_FRONT = {"front": (), "second": ("main",), "third": ("main", "middle"),
                  "back": ("total",)}  # fmt: skip
"""The zones' drafts between each bottom roller and the front roller."""


def runout_um(c: Candidate, drafts: dict[str, float]) -> float | None:
    """The eccentricity (um) of a roller that explains ``c``'s speed modulation, where ``c``
    is a roller's own once-per-revolution line (else None): ``e = m r``, the radius from the
    line's wavelength (``pi d`` times the draft to the front, T8)."""
    name = c.element.removeprefix("roller ")
    if c.kind != "roller" or c.harmonic != 1 or name not in DRAFT_TO_FRONT:
        return None
    if not math.isfinite(c.required_modulation_pct):
        return None
    draft = math.prod(drafts[z] for z in DRAFT_TO_FRONT[name])
    radius_mm = 1e3 * c.wavelength_m / (math.pi * draft) / 2
    return c.required_modulation_pct / 100 * radius_mm * 1e3


def _runout_text(c: Candidate, drafts: dict[str, float]) -> str:
    """What a fitter measures: "; as a run-out of roller second: eccentricity 17 um (TIR 34
    um)"."""
    e = runout_um(c, drafts)
    if e is None:
        return ""
    return f"; as a run-out of {c.element} alone: eccentricity {e:.0f} um (TIR {2 * e:.0f} um)"


def _fmt_m(x: float) -> str:
    return f"{x * 100:.3g} cm" if x < 1 else f"{x:.3g} m"


def ranked_elements(causes: list[ChimneyCause]) -> list[str]:
    """Elements in order of their best placement over all chimneys (for summaries)."""
    best: dict[str, tuple[bool, int, int]] = {}
    for i, cause in enumerate(sorted(causes, key=lambda c: -c.excess_pct)):
        for j, c in enumerate(cause.candidates):
            key = (not c.plausible, i, j)
            if c.element not in best or key < best[c.element]:
                best[c.element] = key
    return [e for e, _ in sorted(best.items(), key=lambda kv: kv[1])]
