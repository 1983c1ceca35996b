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

import math
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from matplotlib.ticker import FixedLocator, FuncFormatter, LogLocator, NullFormatter  # noqa: E402

from drafttwin.report.figures import _png  # noqa: E402
from drafttwin.report.fmt import DASH, is_num  # noqa: E402
from drafttwin.report.html import (  # noqa: E402
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
from drafttwin.sliver.attribution import Candidate, ChimneyCause  # noqa: E402
from drafttwin.sliver.diagnose import SliverDiagnosis  # noqa: E402
from drafttwin.sliver.irregularity import Evenness  # noqa: E402

if TYPE_CHECKING:
    from drafttwin.report.html import BodyRow, Content, Row

__all__ = [
    "causes_table",
    "chimneys",
    "evenness_table",
    "sliver_page",
    "spectrogram_png",
    "summary_box",
    "top_candidate",
    "wavelength_details",
]

RED, DARK_RED, BLUE, PALE, GREY = "#d62728", "#8b1a1a", "#4a7fb0", "#dfe8f1", "#9aa3ad"

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
def chimneys(diagnosis: SliverDiagnosis) -> list[tuple[str, ChimneyCause]]:
    """The chimneys with their labels C1, C2, ...: largest excess over the base first."""
    ordered = sorted(diagnosis.causes, key=lambda c: -c.excess_pct)
    return [(f"C{i + 1}", c) for i, c in enumerate(ordered)]


def top_candidate(cause: ChimneyCause) -> Candidate | None:
    """The first plausible candidate (None: no drive element explains the chimney)."""
    return next((c for c in cause.candidates if c.plausible), None)


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


# ---- the spectrogram figure ---------------------------------------------------------------
def _tick_label(cm: float, _: Any = None) -> str:
    return f"{cm:g} cm" if cm < 100 else f"{cm / 100:g} m"


LABEL_ROW = 0.065
"""Height of one row of element labels at the top of the spectrogram, axes fraction."""
CHAR_WIDTH = 0.0068
"""Rough width of one label character (8.5 pt on the 11 in figure), axes fraction."""


def _element_labels(found: list[tuple[str, ChimneyCause]], x_lo: float, x_hi: float
                    ) -> list[tuple[str, float, bool, int]]:  # fmt: skip
    """The label of each chimney's top candidate (``C1 roller front (+3 look-alikes)``, or
    ``C2 from the feed``): text, wavelength (cm), drawn to the left of its line (near the
    right edge), and its row from the top, rows chosen so that labels do not overlap."""
    span = math.log(x_hi / x_lo)
    placed: list[tuple[str, float, bool, float, float]] = []
    for label, cause in found:
        top = top_candidate(cause)
        if top is not None:
            more = len(top.lookalikes)
            text = f"{label} {top.element}" + (f" (+{more} look-alike{'s' * (more > 1)})"
                                                if more else "")  # fmt: skip
            x = top.wavelength_m * 100
        else:
            text, x = f"{label} from the feed", cause.wavelength_m * 100
        fx = math.log(x / x_lo) / span
        right = fx > 0.7
        width = CHAR_WIDTH * len(text) + 0.01
        placed.append((text, x, right, fx - width if right else fx, fx if right else fx + width))
    rows: list[list[tuple[float, float]]] = []
    out = []
    for text, x, right, a, b in sorted(placed, key=lambda p: p[3]):
        row = next((i for i, r in enumerate(rows)
                    if all(b + 0.005 < c or a > d + 0.005 for c, d in r)), len(rows))  # fmt: skip
        if row == len(rows):
            rows.append([])
        rows[row].append((a, b))
        out.append((text, x, right, row))
    return out


def _chimney_marks(ax: Any, found: list[tuple[str, ChimneyCause]], centre_m: np.ndarray,
                   amp: np.ndarray, top_y: float, x_lo: float, x_hi: float) -> None:  # fmt: skip
    """``C1``, ``C2``, ... above each chimney's bar; a mark that would touch its left
    neighbour's is lifted."""
    span = math.log(x_hi / x_lo)
    marks = []
    for label, cause in found:
        channel = float(cause.extra.get("channel_m", cause.wavelength_m))
        i = int(np.argmin(np.abs(np.log(centre_m / channel))))
        marks.append((math.log(centre_m[i] * 100 / x_lo) / span, centre_m[i] * 100,
                      float(amp[i]) + 0.012 * top_y, label))  # fmt: skip
    last: list[tuple[float, float]] = []
    for fx, x, y, label in sorted(marks):
        for px, py in last:
            if abs(fx - px) < 0.03 and abs(y - py) < 0.06 * top_y:
                y = py + 0.06 * top_y
        last.append((fx, y))
        ax.text(x, y, label, ha="center", va="bottom", fontsize=8, fontweight="bold",
                color=DARK_RED, zorder=5, bbox={"boxstyle": "round,pad=0.1", "fc": "white",
                                                "ec": "none", "alpha": 0.85})  # fmt: skip


def spectrogram_png(diagnosis: SliverDiagnosis) -> bytes:
    """The spectrogram as evenness testers draw it: log wavelength axis in cm, one bar per
    channel (solid: significant, hatched: 6 to 25 periods, red: chimney), the ideal random
    sliver as a line, the base dashed, the chimney level (1.5 x base) dotted, and thin
    vertical lines at the wavelength-table elements near each chimney (top candidate
    labelled)."""
    sp = diagnosis.spectrogram
    lo, hi = sp.edges_m[:, 0] * 100, sp.edges_m[:, 1] * 100
    centre, amp = sp.wavelength_m * 100, np.nan_to_num(sp.amplitude_pct)
    chim = sp.chimney.astype(bool)
    sig = sp.significant.astype(bool) & ~chim
    pale = sp.shown_not_significant.astype(bool) & ~sig & ~chim
    rest = ~(sig | pale | chim)
    fig, ax = plt.subplots(figsize=(11, 4.6))
    bar: dict[str, Any] = {"align": "edge", "linewidth": 0.5, "zorder": 2}
    ax.bar(lo[sig], amp[sig], width=(hi - lo)[sig], color=BLUE, edgecolor="white", **bar)
    ax.bar(lo[pale], amp[pale], width=(hi - lo)[pale], color=PALE, edgecolor="#8fa6bf",
           hatch="////", **bar)  # fmt: skip
    ax.bar(lo[rest], amp[rest], width=(hi - lo)[rest], color="#eceff2", edgecolor=GREY, **bar)
    ax.bar(lo[chim], amp[chim], width=(hi - lo)[chim], color=RED, edgecolor="white", **bar)
    if sp.ideal_pct is not None:
        ax.plot(centre, sp.ideal_pct, color="k", lw=1.3, zorder=4)
    ax.plot(centre, sp.base_pct, color="#333", lw=1.1, ls="--", zorder=4)
    ax.plot(centre, 1.5 * sp.base_pct, color="#777", lw=0.9, ls=":", zorder=4)
    x_lo, x_hi = float(lo.min()) / 1.03, float(hi.max()) * 1.03
    ax.set_xscale("log")
    ax.set_xlim(x_lo, x_hi)
    found = chimneys(diagnosis)
    labels = _element_labels(found, x_lo, x_hi)
    rows = max((r for *_, r in labels), default=-1) + 1
    data_top = max(
        float(amp.max(initial=0.0)),
        float(np.nanmax(1.5 * sp.base_pct, initial=0.0)),
        float(np.nanmax(sp.ideal_pct, initial=0.0)) if sp.ideal_pct is not None else 0.0,
    )
    room = 0.88 - LABEL_ROW * rows  # the labels' rows sit above the data and the marks
    top_y = data_top / room if data_top > 0 else 1.0
    ax.set_ylim(0, top_y)
    for _, cause in found:
        top = top_candidate(cause)
        for c in cause.candidates:
            if c is not top:
                ax.axvline(c.wavelength_m * 100, color=DARK_RED if c.plausible else GREY, lw=0.6,
                           ls="-" if c.plausible else ":", alpha=0.7, zorder=3)  # fmt: skip
        if top is not None:
            ax.axvline(top.wavelength_m * 100, color=DARK_RED, lw=1.1, zorder=3)
    box = {"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.85}
    for text, x, right, row in labels:
        ax.annotate(text, (x, 0.975 - LABEL_ROW * row), xycoords=("data", "axes fraction"),
                    xytext=(-3 if right else 3, 0), textcoords="offset points",
                    ha="right" if right else "left", va="top", fontsize=8.5, color=DARK_RED,
                    bbox=box, zorder=5)  # fmt: skip
    _chimney_marks(ax, found, sp.wavelength_m, amp, top_y, x_lo, x_hi)
    majors = [m * 10.0**e for e in range(-1, 4) for m in (1, 2, 5)]
    ax.xaxis.set_major_locator(FixedLocator([v for v in majors if x_lo <= v <= x_hi]))
    ax.xaxis.set_major_formatter(FuncFormatter(_tick_label))
    ax.xaxis.set_minor_locator(LogLocator(base=10, subs=tuple(range(2, 10))))
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.grid(axis="both", which="major", color="#e3e6ea", lw=0.6, zorder=0)
    ax.set_axisbelow(True)
    ax.set_xlabel("wavelength on the delivered sliver (log scale)")
    ax.set_ylabel("amplitude, %")
    handles = [
        Patch(fc=BLUE, ec="white", label="significant channel (25+ periods)"),
        Patch(fc=PALE, ec="#8fa6bf", hatch="////", label="6–25 periods (not significant)"),
        Patch(fc=RED, ec="white", label="chimney"),
        Line2D([], [], color="k", lw=1.3, label="ideal random sliver"),
        Line2D([], [], color="#333", lw=1.1, ls="--", label="base"),
        Line2D([], [], color="#777", lw=0.9, ls=":", label="chimney level (1.5 × base)"),
        Line2D([], [], color=DARK_RED, lw=1.1, label="machine element near a chimney"),
    ]
    if sp.ideal_pct is None:
        handles.pop(3)
    if rest.any():
        handles.insert(2, Patch(fc="#eceff2", ec=GREY, label="marked not significant"))
    ax.legend(handles=handles, loc="lower center", bbox_to_anchor=(0.5, 1.01), ncol=4,
              fontsize=8.5, frameon=False, borderaxespad=0.2)  # fmt: skip
    fig.tight_layout()
    return _png(fig)


# ---- tables -------------------------------------------------------------------------------
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
    caption = ("Spectrogram: amplitude of each 10-per-octave channel (equivalent sine, % of "
               "the mean). Solid bars are significant, hatched bars have only 6 to 25 periods in "
               "the record, red bars are chimneys. The black line is the ideal random sliver, "
               "the dashed line the base, the dotted line the chimney level (1.5 × base). Thin "
               "vertical lines mark the machine elements near each chimney (dotted: they cannot "
               "leave it); the most likely one is labelled.")  # fmt: skip
    fig = figure(spectrogram_png(diagnosis), "fig-spectrogram", caption, "sliver spectrogram")
    parts: list[Raw] = [
        Raw(f"<style>{CSS}</style>"),
        tag("h1", title),
        para(f"Source: {source}{tested}", cls="sub"),
        summary_box(diagnosis),
        section("spectrogram", "Spectrogram", fig),
        section("causes-section", "Causes of each chimney", causes_table(diagnosis)),
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
