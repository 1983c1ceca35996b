"""The sliver spectrogram as evenness testers draw it, and how the page names its chimneys.

:func:`spectrogram_png` draws one bar per 10-per-octave channel on a log wavelength axis
(significant, 6-25 periods, chimneys in red, the machine's own lines in tan), the ideal random
sliver, the base and the chimney level, and the machine elements near each chimney;
:func:`spectrogram_caption` says what it drew. Chimneys are labelled C1, C2, ... by their
excess over the base (:func:`chimneys`), the same in the figure and on the page
(:mod:`drafttwin.report.sliver`).
"""

from __future__ import annotations

import math
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from matplotlib.ticker import FixedLocator, FuncFormatter, LogLocator, NullFormatter  # noqa: E402

from drafttwin.report.figures import _png  # noqa: E402
from drafttwin.sliver.attribution import Candidate, ChimneyCause  # noqa: E402
from drafttwin.sliver.diagnose import SliverDiagnosis  # noqa: E402

RED, DARK_RED, BLUE, PALE, GREY = "#d62728", "#8b1a1a", "#4a7fb0", "#dfe8f1", "#9aa3ad"
OWN = "#c9a66b"  # a line the machine's healthy reference has too: known, not a chimney


def chimneys(diagnosis: SliverDiagnosis) -> list[tuple[str, ChimneyCause]]:
    """The chimneys with their labels C1, C2, ...: largest excess over the base first."""
    ordered = sorted(diagnosis.causes, key=lambda c: -c.excess_pct)
    return [(f"C{i + 1}", c) for i, c in enumerate(ordered)]


def top_candidate(cause: ChimneyCause) -> Candidate | None:
    """The first plausible candidate (None: no drive element explains the chimney)."""
    return next((c for c in cause.candidates if c.plausible), None)


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
    own = _own_channels(diagnosis, sp.wavelength_m)
    chim = sp.chimney.astype(bool) & ~own
    own &= sp.chimney.astype(bool)
    sig = sp.significant.astype(bool) & ~chim & ~own
    pale = sp.shown_not_significant.astype(bool) & ~sig & ~chim & ~own
    rest = ~(sig | pale | chim | own)
    fig, ax = plt.subplots(figsize=(11, 4.6))
    bar: dict[str, Any] = {"align": "edge", "linewidth": 0.5, "zorder": 2}
    ax.bar(lo[sig], amp[sig], width=(hi - lo)[sig], color=BLUE, edgecolor="white", **bar)
    ax.bar(lo[pale], amp[pale], width=(hi - lo)[pale], color=PALE, edgecolor="#8fa6bf",
           hatch="////", **bar)  # fmt: skip
    ax.bar(lo[rest], amp[rest], width=(hi - lo)[rest], color="#eceff2", edgecolor=GREY, **bar)
    ax.bar(lo[chim], amp[chim], width=(hi - lo)[chim], color=RED, edgecolor="white", **bar)
    ax.bar(lo[own], amp[own], width=(hi - lo)[own], color=OWN, edgecolor="white", **bar)
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
    if own.any():
        handles.insert(
            3, Patch(fc=OWN, ec="white", label="the machine's own line (in the reference)")
        )
    if sp.ideal_pct is None:
        handles = [h for h in handles if h.get_label() != "ideal random sliver"]
    if not pale.any():
        handles = [h for h in handles if not str(h.get_label()).startswith("6–25")]
    if rest.any():
        handles.insert(2, Patch(fc="#eceff2", ec=GREY, label="marked not significant"))
    ax.legend(handles=handles, loc="lower center", bbox_to_anchor=(0.5, 1.01), ncol=4,
              fontsize=8.5, frameon=False, borderaxespad=0.2)  # fmt: skip
    fig.tight_layout()
    return _png(fig)


def _own_channels(diagnosis: SliverDiagnosis, centre_m: np.ndarray) -> np.ndarray:
    """The spectrogram channels of the machine's own lines (chimneys its healthy reference
    has too: ``diagnosis.known``)."""
    own = np.zeros(len(centre_m), dtype=bool)
    for cause in diagnosis.known:
        channel = float(cause.extra.get("channel_m", cause.wavelength_m))
        own[int(np.argmin(np.abs(np.log(centre_m / channel))))] = True
    return own


def spectrogram_caption(diagnosis: SliverDiagnosis) -> str:
    """What the spectrogram draws, as drawn: a tester's export has no record (so no period
    count and no ideal curve unless its fibres are known), a record without a reference no
    own lines."""
    sp = diagnosis.spectrogram
    parts = ["Spectrogram: amplitude of each 10-per-octave channel (equivalent sine, % of the "
             "mean). Solid bars are significant"]  # fmt: skip
    if sp.shown_not_significant.astype(bool).any():
        parts.append(", hatched bars have only 6 to 25 periods in the record")
    parts.append(", red bars are chimneys")
    if diagnosis.known:
        parts.append(", tan bars the machine's own lines (in its healthy reference too)")
    parts.append(". ")
    if sp.ideal_pct is not None:
        parts.append("The black line is the ideal random sliver, the dashed line the base")
    else:
        parts.append("The dashed line is the base")
    parts.append(", the dotted line the chimney level (1.5 × base).")
    if diagnosis.causes:
        parts.append(" Thin vertical lines mark the machine elements near each chimney "
                     "(dotted: they cannot leave it); the most likely one is labelled.")  # fmt: skip
    return "".join(parts)
