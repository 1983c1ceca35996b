"""The sliver page a mill's quality engineer reads: what the sliver says.

One self-contained page (:func:`sliver_page`) from a
:class:`~drafttwin.sliver.diagnose.SliverDiagnosis`, in reading order:

1. a summary box (count, CV, index of irregularity, the chimneys with their likely element);
2. the spectrogram as evenness testers draw it (log wavelength axis, one bar per channel, the
   ideal random sliver, the base, chimneys in red, the machine's elements near each chimney);
3. the causes of each chimney (element, harmonic, gain, the speed modulation it would need,
   look-alikes, the roller encoders' word where present);
4. the evenness figures (a record only, not a tester's spectrogram);
5. the machine's wavelength table, folded;
6. how to read it.

Chimneys are numbered C1, C2, ... by their excess over the base, largest first, the same in
the summary, the figure and the tables.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from drafttwin.report.fmt import DASH, is_num
from drafttwin.report.html import (
    Cell,
    Raw,
    bullets,
    figure,
    join,
    kv_table,
    page,
    para,
    section,
    table,
    tag,
)
from drafttwin.report.sliver_spectrogram import (
    chimneys,
    spectrogram_caption,
    spectrogram_png,
    top_candidate,
)
from drafttwin.sliver.attribution import ChimneyCause
from drafttwin.sliver.diagnose import SliverDiagnosis
from drafttwin.sliver.irregularity import Evenness

if TYPE_CHECKING:
    from drafttwin.report.html import BodyRow, Content, Row

__all__ = [
    "causes_table",
    "diagnosis_section",
    "chimneys",
    "evenness_table",
    "sliver_page",
    "spectrogram_png",
    "summary_box",
    "top_candidate",
    "wavelength_details",
]


CSS = """
.summary { border: 1px solid var(--line); border-left: 6px solid var(--accent);
           background: #f7f9fb; padding: 12px 18px 10px; margin: 12px 0 6px; }
.summary.alarm { border-left-color: #d62728; }
.stats { display: flex; flex-wrap: wrap; gap: 8px 34px; margin: 0 0 8px; }
.stat .v { display: block; font-size: 22px; font-weight: 650; font-variant-numeric: tabular-nums; }
.stat .k { color: var(--muted); font-size: 12px; }
ul.chimneys { list-style: none; margin: 4px 0 2px; padding: 0; }
ul.chimneys li { max-width: none; margin: 6px 0; padding-left: 12px; border-left: 3px solid #d62728; }
ul.chimneys .verdict { display: block; color: var(--muted); font-size: 13px; }
.summary .none { margin: 4px 0; font-weight: 600; color: #2a6f3e; }
.summary .note { margin: 6px 0 0; }
details { margin: 10px 0; }
details > summary { cursor: pointer; font-weight: 600; color: var(--accent); }
tr.cand td { background: #fdeeee; }
#causes td { width: 1%; }
#causes td.wrap { width: auto; }
#causes td.wrap, #causes th.wrap { min-width: 150px; }
#causes td.enc, #causes th.enc { min-width: 190px; }
ul.read li { margin: 4px 0; }
"""


# ---- formatting ---------------------------------------------------------------------------
def _length(m: float) -> str:
    """A wavelength: ``14.1 cm`` below a metre, ``1.28 m`` above."""
    if not is_num(m):
        return DASH
    return f"{m * 100:.3g} cm" if m < 1 else f"{m:.3g} m"


def _pct(x: float) -> str:
    return f"{x:.2f} %" if is_num(x) else DASH


def _g(x: Any, digits: int = 3) -> str:
    return f"{x:.{digits}g}" if is_num(x) else DASH


def _cm(m: float) -> str:
    """A wavelength in cm for a table column."""
    return f"{m * 100:.2f}" if is_num(m) else DASH


# ---- chimneys -----------------------------------------------------------------------------
def _encoder_share(cause: ChimneyCause) -> float | None:
    share = cause.extra.get("encoder_share")
    return float(share) if is_num(share) else None


def _encoders(cause: ChimneyCause) -> dict[str, dict[str, Any]]:
    """The encoders' checks of a chimney by element (empty without encoders)."""
    return {str(k.get("element")): k for k in cause.extra.get("encoders", []) or []}


def _chimney_line(label: str, cause: ChimneyCause) -> Raw:
    """``C1 · 14.1 cm, 0.51 % (base 0.18 %): roller front — look-alikes: ...`` and the
    verdict below it."""
    head = tag("strong", f"{label} · {_length(cause.wavelength_m)}")
    level = f", {_pct(cause.amplitude_pct)} (base {_pct(cause.base_pct)}): "
    top = top_candidate(cause)
    if top is None:
        what = join([tag("strong", "from the feed"),
                     f" — a defect at {_length(cause.fed_wavelength_m)} on the fed sliver"])  # fmt: skip
    else:
        harmonic = f" (harmonic {top.harmonic})" if top.harmonic != 1 else ""
        alike = f" — look-alikes: {', '.join(top.lookalikes)}" if top.lookalikes else ""
        what = join([tag("strong", top.element), harmonic, alike])
    share = _encoder_share(cause)
    verdict = cause.verdict
    if share is not None and "encoders explain" not in verdict:
        verdict += f"; the roller encoders explain {share:.0%} of it"
    return tag("li", join([head, level, what, tag("span", verdict, cls="verdict")]))


def summary_box(diagnosis: SliverDiagnosis) -> Raw:
    """The first screen: count, CV, index of irregularity, the chimneys and their elements."""
    ev = diagnosis.evenness
    found = chimneys(diagnosis)

    def stat(value: str, key: str) -> Raw:
        return tag("div", join([tag("span", value, cls="v"), tag("span", key, cls="k")]),
                   cls="stat")  # fmt: skip

    if ev is not None:
        stats = [stat(f"{ev.count_ktex:.3g} ktex", "count"), stat(f"{ev.cv_pct:.2f} %", "CV"),
                 stat(_g(ev.index_of_irregularity), "index of irregularity"),
                 stat(_length(ev.length_m), "tested length")]  # fmt: skip
    else:
        stats = [stat(DASH, "count, CV, index: a tester's spectrogram, no record")]
    stats.append(stat(str(len(found)), "significant chimneys" if len(found) != 1 else
                      "significant chimney"))  # fmt: skip
    if found:
        listing = tag("ul", join(_chimney_line(label, c) for label, c in found), cls="chimneys")
    else:
        listing = para("No significant chimney: no channel rises above its base by more than "
                       "half the base with statistical significance.", cls="none")  # fmt: skip
    note = para("Each chimney: its wavelength on the delivered sliver, its amplitude and the "
                "local base; then the element most likely behind it and those that leave the same "
                "wavelength (the sliver cannot tell them apart).", cls="note")  # fmt: skip
    parts = [tag("div", join(stats), cls="stats"), listing, *([note] if found else [])]
    return tag("div", join(parts),
               cls="summary alarm" if found else "summary", id="summary")  # fmt: skip


def _encoder_cell(check: dict[str, Any] | None) -> Cell:
    """The encoders' verdict on one candidate, short (``ruled out``, ``confirmed by the
    encoders``, ...), with the line it would need, the measured line and the noise; the full
    verdict as the tooltip."""
    if not check:
        return Cell(DASH, cls="wrap enc")
    verdict = str(check.get("verdict", DASH))
    short = verdict.split(":")[0].split(" (")[0]
    numbers = (f"expected {_g(check.get('expected_pct'), 2)} %, measured "
               f"{_g(check.get('measured_pct'), 2)} %, noise {_g(check.get('noise_pct'), 2)} %")  # fmt: skip
    return Cell(join([tag("strong", short), Raw("<br>"), numbers]), cls="wrap enc", title=verdict)


def own_lines(diagnosis: SliverDiagnosis) -> Raw | None:
    """A line naming the machine's own lines, or ``None`` when there are none."""
    if not diagnosis.known:
        return None
    lines = ", ".join(f"{_length(c.wavelength_m)} at {_pct(c.amplitude_pct)}"
                      for c in sorted(diagnosis.known, key=lambda c: c.wavelength_m))  # fmt: skip
    return para(f"The machine's own lines, in its healthy reference too and so not new (drawn "
                f"in tan, not as chimneys): {lines}.")  # fmt: skip


def causes_table(diagnosis: SliverDiagnosis) -> Raw:
    """One group row per chimney, then its candidates in rank order."""
    found = chimneys(diagnosis)
    if not found:
        return para("No chimney, so no cause to name.")
    with_enc = any(_encoders(c) or _encoder_share(c) is not None for _, c in found)
    wrap = "wrap"
    head: list[Row] = [["rank", Cell("element", cls="name", header=True), "kind", "harmonic",
                        "its wavelength, cm", Cell("gain", header=True,
                                                   title="speed-to-mass gain at this wavelength"),
                        "speed modulation needed, %", "plausible",
                        Cell("look-alikes (same wavelength)", cls=wrap, header=True)]]  # fmt: skip
    if with_enc:
        head[0] = [*head[0], Cell("roller encoders", cls="wrap enc", header=True)]
    width = len(head[0])
    body: list[BodyRow] = []
    for label, cause in found:
        share = _encoder_share(cause)
        top = top_candidate(cause)
        parts = [f"{label} · {_length(cause.wavelength_m)} · {_pct(cause.amplitude_pct)} over a "
                 f"base of {_pct(cause.base_pct)} (excess {_pct(cause.excess_pct)})",
                 f"most likely {top.element}" if top is not None else
                 f"from the feed: a defect at {_length(cause.fed_wavelength_m)} on the fed "
                 "sliver"]  # fmt: skip
        if share is not None:
            parts.append(f"the roller encoders explain {100 * share:.0f} % of it")
        body.append(("group", [Cell(" · ".join(parts), cls=wrap, colspan=width)]))
        checks = _encoders(cause)
        for i, c in enumerate(cause.candidates):
            need = (f"{c.required_modulation_pct:.2f}" if is_num(c.required_modulation_pct)
                    else DASH)  # fmt: skip
            row: list[Cell | Content] = [
                str(i + 1), Cell(c.element, cls="name"), Cell(c.kind, cls="name"),
                str(c.harmonic),
                _cm(c.wavelength_m), f"{c.gain:.2f}",
                Cell(need, title=None if c.plausible else "its gain is below 0.05: it moves "
                     "the rollers alike and cannot make a chimney"),
                Cell("yes" if c.plausible else "no", cls="yes" if c.plausible else "no"),
                Cell(", ".join(c.lookalikes) or DASH, cls=wrap)]  # fmt: skip
            if with_enc:
                row.append(_encoder_cell(checks.get(c.element)))
            body.append(row)
        if not cause.candidates:
            body.append([Cell("no element of the wavelength table lies in this channel",
                              cls=wrap, colspan=width)])  # fmt: skip
    return table(head, body, id="causes")


def evenness_table(ev: Evenness) -> Raw:
    """Count, CV, U, CV at the cut lengths, Martindale's limit and the index of
    irregularity."""
    items: dict[str, Any] = {
        "count, ktex": f"{ev.count_ktex:.4g}",
        "CV, %": f"{ev.cv_pct:.2f}",
        "U, %": f"{ev.u_pct:.2f}",
    }
    for cut, cv in ev.cv_cut_pct.items():
        items[f"CV at {cut}, %"] = f"{cv:.2f}" if is_num(cv) else f"{DASH} (too few pieces)"
    items["Martindale's limit CV, %"] = (f"{ev.martindale_cv_pct:.2f}"
                                         if is_num(ev.martindale_cv_pct) else DASH)  # fmt: skip
    items["index of irregularity (CV / limit)"] = _g(ev.index_of_irregularity)
    items["tested length, m"] = f"{ev.length_m:.4g}"
    items["grid step, mm"] = f"{ev.step_m * 1000:g}"
    return kv_table(items, id="evenness-table")


def wavelength_details(diagnosis: SliverDiagnosis) -> Raw:
    """The machine's wavelength table in a folded ``<details>``; elements named for a chimney
    are shaded and carry its label."""
    wt = diagnosis.table
    named: dict[str, list[str]] = {}
    for label, cause in chimneys(diagnosis):
        for c in cause.candidates:
            if c.plausible and label not in named.setdefault(c.element, []):
                named[c.element].append(label)
    harmonics = range(2, min(wt.harmonics, 4) + 1)  # the first three: the table fits
    head: list[Row] = [[Cell("element", cls="name", header=True), "kind", "turns with",
                        "frequency, Hz", "wavelength, cm",
                        *[f"λ/{h}, cm" for h in harmonics],
                        Cell("moves the rollers", cls="wrap", header=True),
                        "chimney"]]  # fmt: skip
    body: list[BodyRow] = []
    for e in wt.elements:
        row: Row = [Cell(e.name, cls="name"), Cell(e.kind, cls="name"),
                    Cell(e.node or DASH, cls="name"), f"{e.frequency_hz:.2f}",
                    _cm(e.wavelength_m), *[_cm(e.wavelength_m / h) for h in harmonics],
                    Cell(", ".join(e.rollers) or DASH, cls="wrap"),
                    Cell(", ".join(named.get(e.name, [])), cls="name")]  # fmt: skip
        body.append(("cand", row) if e.name in named else row)
    drafts = ", ".join(f"{k} {v:.3g}" for k, v in diagnosis.drafts.items())
    intro = para(f"Train {wt.train} at its running point: delivery {wt.delivery_m_min:.4g} m/min, "
                 f"motor {wt.motor_rpm:.4g} rpm; drafts {drafts}. Each element's line on the "
                 "sliver is the delivery speed over its frequency; shaded rows are named for a "
                 "chimney.", cls="note")  # fmt: skip
    summary = tag("summary", f"All {len(wt.elements)} rotating elements of {wt.train} with "
                             "their frequency and wavelength (click to open)")  # fmt: skip
    return tag("details", join([summary, intro, table(head, body, id="wavelengths")]),
               id="wavelength-table")  # fmt: skip


HOW_TO_READ: tuple[tuple[str, str], ...] = (
    ("A chimney", " is a channel that rises above its base (the larger of the ideal curve and "
     "the median of its neighbours) by more than half the base, and whose rise is statistically "
     "significant (a chi-square test over the channels with at least 25 periods in the record; "
     "hatched channels, 6 to 25 periods, are never flagged)."),
    ("Every rotating element", " leaves its line at the delivery speed over its frequency "
     "(a non-sinusoidal defect also at a half, a third, ... of it). Elements whose lines share a "
     "wavelength are look-alikes: the sliver alone cannot tell them apart; the roller encoders "
     "or an inspection can."),
    ("A rattle line", " sits at half a mesh's or a chain's tooth frequency (twice its "
     "wavelength): a lightly loaded mesh with backlash that loses contact once every two teeth. "
     "It comes with the gears' backlash and light load; one that grows points to backlash "
     "grown by wear."),
    ("The speed modulation needed", " is what the element would have to do to the rollers it "
     "drives to leave this chimney through the drafting. An element that moves every roller "
     "alike (gain near 0) cannot leave one."),
    ("A chimney that no drive element explains", " comes from the feed: its wavelength divided "
     "by the total draft is the wavelength of the defect on the fed sliver (a card or an "
     "earlier passage)."),
)  # fmt: skip


def sliver_page(diagnosis: SliverDiagnosis, *, title: str, source: str) -> str:
    """The whole self-contained page for one sliver's diagnosis; ``source`` names the record
    (or the tester's export) it was made from."""
    sp = diagnosis.spectrogram
    tested = (f" · {sp.length_m:.4g} m on a {sp.step_m * 1000:g} mm grid"
              if is_num(sp.length_m) else " · an evenness tester's spectrogram")  # fmt: skip
    caption = spectrogram_caption(diagnosis)
    fig = figure(spectrogram_png(diagnosis), "fig-spectrogram", caption, "sliver spectrogram")
    parts: list[Raw] = [
        Raw(f"<style>{CSS}</style>"),
        tag("h1", title),
        para(f"Source: {source}{tested}", cls="sub"),
        summary_box(diagnosis),
        section("spectrogram", "Spectrogram", fig),
        section(
            "causes-section",
            "Causes of each chimney",
            join([causes_table(diagnosis), own_lines(diagnosis) or Raw("")]),
        ),
    ]
    if diagnosis.evenness is not None:
        parts.append(section("evenness", "Evenness", evenness_table(diagnosis.evenness)))
    parts += [
        section("machine", "The machine's wavelengths", wavelength_details(diagnosis)),
        section(
            "how-to-read",
            "How to read this",
            bullets([join([tag("strong", a), b]) for a, b in HOW_TO_READ], cls="read"),
        ),
    ]
    return page(title, join(parts))


def diagnosis_section(evidence: Mapping[str, Any], diagnosis: SliverDiagnosis) -> Raw:
    """The sliver channel's part of the diagnosis page (``drafttwin diagnose`` on a record
    with a sliver): its count and CV, the chimneys the running watch alarmed on and where,
    the whole record's chimneys with their causes, the machine's own lines, the spectrogram.
    ``evidence`` is :func:`~drafttwin.diagnosis.sliver_evidence.sliver_evidence`'s summary."""
    ref = evidence.get("reference")
    parts: list[Content] = [para(
        f"Sliver channel {evidence['file']}: count {evidence['count_ktex']:.4f} ktex, CV "
        f"{evidence['cv_pct']:.3f} %" + (f"; its own lines from {ref}" if ref else "") + ".")]  # fmt: skip
    alarms = evidence.get("alarms", [])
    if alarms:
        rows: list[Row] = [[f"{a['time_s']:.1f}", f"{a['delivered_m']:.0f}",
                            _cm(a["wavelength_m"]), _pct(a["amplitude_pct"]), _pct(a["base_pct"]),
                            a["element"], Cell(", ".join(a["lookalikes"]) or DASH, cls="wrap")]
                           for a in alarms]  # fmt: skip
        head: list[Row] = [["alarm at, s", "delivered, m", "chimney, cm", "amplitude",
                            "base", "element", Cell("look-alikes", cls="wrap", header=True)]]  # fmt: skip
        parts += [tag("h3", "Alarms of the running watch"), table(head, rows, id="sliver-alarms")]
    found = chimneys(diagnosis)
    if found:
        parts.append(tag("h3", "The whole record's chimneys"))
        parts.append(bullets([f"{label} · {_length(c.wavelength_m)} · {_pct(c.amplitude_pct)} "
                              f"over a base of {_pct(c.base_pct)}: {c.verdict}"
                              for label, c in found]))  # fmt: skip
    elif not alarms:
        parts.append(para("No significant chimney."))
    known = own_lines(diagnosis)
    if known is not None:
        parts.append(known)
    parts.append(figure(spectrogram_png(diagnosis), "fig-sliver-spectrogram",
                        spectrogram_caption(diagnosis), "sliver spectrogram"))  # fmt: skip
    return join(parts)
