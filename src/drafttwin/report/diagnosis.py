"""The diagnosis page a maintenance engineer reads: alarm, ranked causes, evidence.

The summary says which rule raised the alarm (CUSUM, lag jump, sensor rule), the top cause
with its look-alike group and whether it fits. Three figures: the residual timeline with the
statistic of the rule that fired against its own limit; the spectrum after the change with
every kinematic line marked (the implicated ones in red); the drive train with the suspected
element highlighted (its non-separable group in orange). The detector's settings as a short
table of its three rules.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from drafttwin.data.series import MeasurementSeries  # noqa: E402
from drafttwin.diagnosis.cusum import STREAMS, Alarm, stream_matrix  # noqa: E402
from drafttwin.diagnosis.detect import STILL_CHANNELS, STILL_FACTOR  # noqa: E402
from drafttwin.diagnosis.diagnose import Diagnosis  # noqa: E402
from drafttwin.diagnosis.locate import Cause, told_apart  # noqa: E402
from drafttwin.diagnosis.residuals import CHANNELS, runs_of  # noqa: E402
from drafttwin.diagnosis.spectrum import kinematic_lines, residual_samples, spectrum  # noqa: E402
from drafttwin.mechanics import DriveTrain  # noqa: E402
from drafttwin.report.figures import _png  # noqa: E402
from drafttwin.report.html import Cell, figure, join, page, para, section, table, tag  # noqa: E402
from drafttwin.report.sliver import diagnosis_section  # noqa: E402
from drafttwin.sliver.diagnose import SliverDiagnosis  # noqa: E402

if TYPE_CHECKING:
    from drafttwin.report.html import Raw, Row

RED, ORANGE, GREY = "#d62728", "#ff9f1c", "#b0b7c3"
RULE_NAMES = {"cusum": "CUSUM", "jump": "lag jump rule", "sensor": "sensor rule"}


def _decided(dx: Diagnosis) -> np.ndarray:
    """Blocks the streams' rules decided: not a reference window, not after the alarm."""
    decided: np.ndarray = np.isfinite(dx.detection.deviation).all(axis=1)
    if dx.alarm is not None:
        decided &= np.arange(len(decided)) <= dx.alarm.block
    return decided


def rule_statistic(dx: Diagnosis) -> tuple[np.ndarray, str, str]:
    """The statistic of the rule that raised the alarm over its own limit, per block (1 =
    the limit; NaN where it did not decide), its label and the limit's name; with no alarm,
    the largest CUSUM."""
    det, a = dx.detection, dx.alarm
    rule = a.rule if a is not None else "cusum"
    if rule == "sensor" and a is not None and det.sensor is not None:
        kind, channel = a.test.split("_", 1)
        j = CHANNELS.index(channel) + (len(CHANNELS) if kind == "stuck" else 0)
        still = f"; any run: {STILL_FACTOR:g} x the run limit" if STILL_CHANNELS[
            CHANNELS.index(channel)] else ""  # fmt: skip
        what = f"run of one value (moving its lag{still})" if kind == "stuck" else (
            "samples lost alone")  # fmt: skip
        return det.sensor[:, j], f"{channel}: {what} / its limit", "limit from healthy records"
    if rule == "jump" and a is not None and det.jump is not None:
        i = STREAMS.index(a.test)
        value, label = det.jump[:, i], f"{a.test}: |one-block innovation| / jump limit"
        limit = "jump limit"
    elif a is not None and a.test in STREAMS:
        i = STREAMS.index(a.test)
        value, label, limit = det.statistic[:, i], f"{a.test}: CUSUM / h", "threshold h"
    else:
        value, label, limit = det.statistic.max(axis=1), "largest CUSUM / h", "threshold h"
    return np.where(_decided(dx), value, np.nan), label, limit


def timeline_png(dx: Diagnosis) -> bytes:
    f, det = dx.features, dx.detection
    fig, (ax, lx, bx) = plt.subplots(3, 1, figsize=(10, 7.0), sharex=True)
    streams = det.deviation @ stream_matrix().T
    for i, name in enumerate(STREAMS[:3]):
        ax.plot(f.time_s, 100 * streams[:, i], lw=1, label=name)
    ax.set_ylabel("level vs baseline, %")
    ax.legend(fontsize=8, ncol=3, loc="upper left")
    for i, name in enumerate(STREAMS):  # the rollers' angle lags behind the front roller
        if name.startswith("lag_"):
            lx.plot(f.time_s, streams[:, i], lw=1, label=name)
    lx.set_ylabel("angle lag vs baseline, mrad")
    lx.legend(fontsize=8, ncol=3, loc="upper left")
    value, label, limit = rule_statistic(dx)
    rule = RULE_NAMES[dx.alarm.rule] if dx.alarm is not None else "CUSUM"
    bx.plot(f.time_s, value, color="#1f5f8b", lw=1.2, marker=".", ms=3, label=label)
    if dx.alarm is not None and dx.alarm.rule != "cusum":  # the CUSUMs, for comparison
        cusum = np.where(_decided(dx), det.statistic.max(axis=1), np.nan)
        bx.plot(f.time_s, cusum, color=GREY, lw=0.8, label="largest CUSUM / h (did not fire)")
    bx.axhline(1.0, color="k", ls="--", lw=0.8, label=limit)
    bx.set_yscale("symlog", linthresh=1.0)  # the limit and a jump many times it, both legible
    bx.set_ylim(bottom=0.0)
    bx.set_ylabel(f"{rule}: statistic / limit")
    bx.set_xlabel("time, s")
    if dx.alarm is not None:
        for a in (ax, lx, bx):
            a.axvline(dx.alarm.time_s, color=RED, lw=1.5)
            a.axvspan(dx.alarm.change_s, dx.alarm.time_s, color=RED, alpha=0.1)
    for start, end in dx.not_steady_s():  # a start, a stop, a speed change: not judged
        for a in (ax, lx, bx):
            a.axvspan(start, end, color=GREY, alpha=0.25, lw=0)
    if len(f.time_s):
        bx.set_xlim(float(f.time_s[0] - f.block_s), float(f.time_s[-1]))
    bx.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    return _png(fig)


def _spectrum_rows(dx: Diagnosis, time_s: np.ndarray) -> np.ndarray:
    """The rows the spectrum is taken over: after the alarm (the whole record without one),
    the longest stretch of them that is steady running (a stop's or a start's residual
    would drown the lines)."""
    ok = time_s > (dx.alarm.time_s if dx.alarm is not None else -np.inf)
    for start, end in dx.not_steady_s():
        ok &= ~((time_s > start) & (time_s <= end))
    runs = runs_of(ok)
    if not runs:
        return np.zeros(0, dtype=int)
    a, b = max(runs, key=lambda ab: ab[1] - ab[0])
    return np.arange(a, b)


def spectrum_png(dx: Diagnosis, train: DriveTrain, series: MeasurementSeries) -> bytes:
    rate = series.sample_rate_hz
    r = residual_samples(series)
    after = r[_spectrum_rows(dx, np.asarray(series.time_s, dtype=np.float64))]
    fig, ax = plt.subplots(figsize=(10, 4))
    for j, ch in enumerate(CHANNELS):
        if len(after) >= 16:
            freqs, amp = spectrum(after[:, j], rate)
            ax.semilogy(freqs[1:], 100 * amp[1:] + 1e-9, lw=0.8, label=ch)
    motor = float(np.nanmedian(series.motor_rpm)) if series.motor_rpm is not None else 0.0
    implicated = {ln.freq_hz for ln in dx.lines}
    if motor > 0:
        for name, f, _ in kinematic_lines(train, motor, rate):
            hit = f in implicated
            ax.axvline(
                f, color=RED if hit else GREY, lw=1.4 if hit else 0.6, ls="-" if hit else ":"
            )
            if hit:
                ax.annotate(name, (f, ax.get_ylim()[1]), fontsize=7, color=RED, rotation=90,
                            va="top", ha="right")  # fmt: skip
    ax.set_xlabel("frequency, Hz (kinematic lines dotted, implicated in red)")
    ax.set_ylabel("amplitude, % of speed")
    ax.legend(fontsize=8, ncol=5)
    fig.tight_layout()
    return _png(fig)


def train_png(train: DriveTrain, suspect: set[str], group: set[str]) -> bytes:
    """Nodes as boxes left to right from the motor; couplings as lines."""
    names = train.node_names
    depth = {train.node_index(train.spec.root_node): 0}
    children: dict[int, list[int]] = {}
    for e in train.edges:
        depth[e.child] = depth[e.parent] + 1
        children.setdefault(e.parent, []).append(e.child)
    row: dict[int, float] = {}
    counter = [0.0]

    def place(n: int) -> None:
        kids = children.get(n, [])
        for k in kids:
            place(k)
        if kids:
            row[n] = float(np.mean([row[k] for k in kids]))
        else:
            row[n], counter[0] = counter[0], counter[0] + 1

    place(train.node_index(train.spec.root_node))
    rollers = {r.node: r.name for r in train.spec.roller}
    fig, ax = plt.subplots(figsize=(10, 0.9 + 0.75 * counter[0]))

    def color(*keys: str) -> str:
        if suspect & set(keys):
            return RED
        return ORANGE if group & set(keys) else GREY

    for e in train.edges:
        c = color(e.coupling.name)
        ax.plot([depth[e.parent], depth[e.child]], [row[e.parent], row[e.child]], color=c,
                lw=4 if c != GREY else 1.5, zorder=1)  # fmt: skip
        ax.text((depth[e.parent] + depth[e.child]) / 2, (row[e.parent] + row[e.child]) / 2 + 0.1,
                _wrapped(e.coupling.name), fontsize=7, ha="center", va="bottom",
                color=c if c != GREY else "k", zorder=3,
                bbox={"boxstyle": "square,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.8})  # fmt: skip
    for i, n in enumerate(names):
        label = n + (f"\n({rollers[n]} roller)" if n in rollers else "")
        c = color(n, rollers.get(n, "\0"))
        ax.text(depth[i], row[i], label, ha="center", va="center", fontsize=7,
                bbox={"boxstyle": "round", "fc": c if c != GREY else "#eef1f5", "ec": "k"},
                zorder=2)  # fmt: skip
    ax.set_xlim(-0.6, max(depth.values()) + 0.6)
    ax.set_ylim(-0.8, counter[0] - 0.2)
    ax.axis("off")
    fig.tight_layout()
    return _png(fig)


def _wrapped(name: str, width: int = 12) -> str:
    """A coupling's name on two lines at its last underscore when longer than ``width``: a
    short coupling's one-line label ran into the boxes at its ends."""
    head, sep, tail = name.rpartition("_")
    return f"{head}\n{tail}" if len(name) > width and sep and head else name


def _suspects(dx: Diagnosis, train: DriveTrain) -> tuple[set[str], set[str]]:
    if not dx.causes:
        return set(), set()
    top = dx.causes[0]
    rollers: dict[str, str] = {str(r.name): r.node for r in train.spec.roller}

    def where(element: str, family: str) -> str:
        if family == "sensor":  # the encoder sits on its roller's (or the motor's) node
            return rollers.get(element, train.spec.root_node)
        return element

    suspect = {where(top.element, top.family)}
    group = {where(n.split(":")[0], top.family) for n in look_alikes(top, dx.causes)[0]}
    return suspect, group - suspect


def look_alikes(c: Cause, causes: Sequence[Cause]) -> tuple[list[str], list[str]]:
    """The candidates of ``c``'s group that cannot be told apart from it (they fit where it
    fits), and those its fit tells apart (same direction, but they do not fit here: a belt
    ramp's page had said "cannot be told apart from motor:gain" beside "motor:gain does not
    fit, p 2.3e-14")."""
    apart = told_apart(c.group, getattr(c, "fits", True),
                       {x.name: getattr(x, "fits", True) for x in causes})  # fmt: skip
    return [n for n in c.group if n not in apart], apart


def _group_text(c: Cause, causes: Sequence[Cause]) -> str:
    same, apart = look_alikes(c, causes)
    text = ", ".join(same) or "-"
    return text + (f" (same direction, no fit: {', '.join(apart)})" if apart else "")


def _fit_text(c: Cause) -> str:
    """The cause's absolute fit, where the ranking gives one (read defensively: older
    causes have none)."""
    fit_p, chi2, dof = getattr(c, "fit_p", None), getattr(c, "chi2", None), getattr(c, "dof", 0)
    if fit_p is None or chi2 is None or not dof:
        return "-"
    verdict = "fits" if getattr(c, "fits", True) else "does not fit"
    return f"{verdict}, p {fit_p:.2g} (χ² {chi2:.3g} on {dof})"


def _interval_text(c: Cause) -> str:
    """The interval as the ranking words it ("at least" at a range limit), else ``[lo, hi]``."""
    text = getattr(c, "interval_text", None)
    text = text() if callable(text) else text
    return text if isinstance(text, str) else f"[{c.interval[0]:.3g}, {c.interval[1]:.3g}]"


def _growth_text(c: Cause) -> str | None:
    """A line for a fault still growing at the end of the record, where the ranking says so."""
    g = getattr(c, "growth", None)
    if g is None or not getattr(g, "growing", False):
        return None
    return (f"Still growing: {g.rate_per_s:.3g} per s; {g.severity:.4g} [{g.interval[0]:.3g}, "
            f"{g.interval[1]:.3g}] at {g.at_time_s:.1f} s.")  # fmt: skip


def why_text(a: Alarm, dx: Diagnosis) -> str:
    """Which rule raised the alarm, on what, and by how much over its limit."""
    value, _, limit = rule_statistic(dx)
    over = float(value[a.block]) if 0 <= a.block < len(value) else float("nan")
    by = f", {over:.3g} times its {limit}" if np.isfinite(over) and over > 0 else ""
    return (f"Alarm at {a.time_s:.1f} s raised by the {RULE_NAMES.get(a.rule, a.rule)} on "
            f"{a.test}{by}; change estimated at {a.change_s:.1f} s.")  # fmt: skip


def summary(dx: Diagnosis, reference_s: float | None = None) -> Raw:
    """The banner: the rule that fired, the top cause, its look-alike group and its fit."""
    a = dx.alarm
    steady = dx.steady_note(reference_s) if reference_s is not None else None
    if a is None:
        return join([para("No alarm: the residuals stayed within the thresholds set from "
                          "healthy data."), para(f"Note: {steady}.") if steady else ""])  # fmt: skip
    top = dx.causes[0] if dx.causes else None
    lines = [tag("strong", why_text(a, dx))]
    if top is None:
        lines.append(para("No candidate was evaluated (too little of the record after the alarm)."))
    else:
        fit = _fit_text(top)
        lines.append(para(f"Most likely {top.name} ({top.family}), severity {top.severity:.4g} "
                          f"{_interval_text(top)} {top.parameter}"
                          + ("." if fit == "-" else f"; {fit}.")))  # fmt: skip
        grows = _growth_text(top)
        if grows:
            lines.append(para(grows))
        same, apart = look_alikes(top, dx.causes)
        lines.append(para(
            f"Cannot be told apart from {', '.join(same)} with these sensors: read the "
            "group, not the first name." if same else
            "No other candidate moves the measured channels the same way."
            if not apart else "No other fitting candidate moves the measured channels the "
            f"same way ({', '.join(apart)}: the same direction, but no fit here)."))  # fmt: skip
    verdict = getattr(dx, "verdict", None)
    if isinstance(verdict, str) and verdict:
        lines.append(para(f"Verdict: {verdict}."))
    if steady:
        lines.append(para(f"Note: {steady}."))
    return tag("div", join(lines), cls="banner")


def _rule_rows(d: Mapping[str, Any]) -> list[list[str]]:
    """Per rule: its name, what it watches, when it alarms, where its limit comes from."""
    nan = float("nan")
    streams = d.get("streams") or {}
    watched = [s for s, v in streams.items() if v.get("watched", True)]
    lags = [s for s in watched if s.startswith("lag_")]
    levels = ", ".join(s for s in watched if not s.startswith("lag_"))
    jumps = ", ".join(f"{s} {streams[s].get('jump_limit', 0):.3g}" for s in lags
                      if streams[s].get("jump_limit", 0) > 0) or "off"  # fmt: skip
    runs = ", ".join(
        f"{c} {v:.0f}"
        for c, v in (d.get("run_limit") or {}).items()
        if STILL_CHANNELS[CHANNELS.index(c)]
    )  # the channels the length test judges
    stale = ", ".join(f"{c} {v:.0f}" for c, v in (d.get("stale_limit") or {}).items())
    losts = ", ".join(f"{c} {100 * v:.1f} %" for c, v in (d.get("lost_limit") or {}).items())
    return [
        ["CUSUM", levels + (f"; angle lags {', '.join(lags)}" if lags else ""),
         f"h = {d.get('h', nan):.3g} (k = {d.get('k', nan):.3g}) in whitened units",
         f"Siegmund's run length for {d.get('far_per_day', nan):g} false alarm(s) per 24 h "
         "over all streams; scales, AR(1) and long-run variance from the healthy records"],
        ["lag jump", ", ".join(lags) or "off (healthy records too short)",
         f"one block's innovation over: {jumps} (its own units)",
         "twice the largest in the healthy records"],
        ["sensor rules", "every channel",
         f"run of one value that moves the channel's angle lag (samples): {stale}; any run "
         f"of one value of the front roller and the motor: {STILL_FACTOR:g} x ({runs}); "
         f"samples lost alone: {losts}",
         f"the longest healthy run (twice the longest that moved its lag, if longer); "
         f"{STILL_FACTOR:g} x twice the longest healthy run; the most lost in a healthy block "
         "+ 2 %"],
    ]  # fmt: skip


def detector_table(info: Mapping[str, Any]) -> Raw:
    """The detector's three rules as a short table (what each watches, its limit, where the
    limit comes from), read from :meth:`FaultDetector.describe` in ``info``, and a line on
    its baseline and where its thresholds came from."""
    d, nan = info.get("detector") or {}, float("nan")
    rows: list[Row] = [[Cell(name, cls="name"), *(Cell(x, cls="wrap") for x in rest)]
                       for name, *rest in _rule_rows(d)]  # fmt: skip
    head: list[Row] = [["rule", *(Cell(h, cls="wrap", header=True)
                                  for h in ("watches", "alarms above", "limit from"))]]  # fmt: skip
    unwatched = [s for s, v in (d.get("streams") or {}).items() if not v.get("watched", True)]
    creep = info.get("creep_rel_sd")
    base = (f"Blocks of {d.get('block_s', nan):g} s; each record's baseline is its first "
            f"{d.get('reference_s', nan):g} s, then follows slow drift (EWMA, "
            f"{d.get('drift_tau_s', nan):g} s) while nothing is suspicious. Thresholds from "
            f"{info.get('thresholds_from', '-')}; physics {info.get('physics', '-')}"
            + (f"; belt-creep mismatch {100 * creep:.0f} % of the physics' creep"
               if isinstance(creep, float) else "")
            + (f". Not watched: {', '.join(unwatched)}." if unwatched else "."))  # fmt: skip
    walk = d.get("lag_walk_mrad2_per_block") or {}
    if walk and isinstance(d.get("block_s"), int | float):
        per_min = ", ".join(f"lag_{name} {math.sqrt(max(float(q), 0.0) * 60.0 / d['block_s']):.1f}"
                            for name, q in walk.items())  # fmt: skip
        base += (f" The angle lags random-walk by {per_min} mrad per minute (SD, measured on "
                 "the healthy records); the severity intervals of gear wear and chain "
                 "elongation carry it.")  # fmt: skip
    return join([table(head, rows, id="detector"), para(base, cls="note")])


def render_diagnosis(dx: Diagnosis, train: DriveTrain, series: MeasurementSeries,
                     info: Mapping[str, Any], title: str = "Fault diagnosis",
                     sliver: tuple[Mapping[str, Any], SliverDiagnosis] | None = None) -> str:  # fmt: skip
    """The whole self-contained page; ``sliver``: the record's sliver channel's evidence and
    diagnosis (:func:`~drafttwin.diagnosis.sliver_evidence.sliver_evidence`), shown after
    the verdict."""
    detector = info.get("detector")
    reference_s = detector.get("reference_s") if isinstance(detector, Mapping) else None
    verdict = summary(dx, float(reference_s) if reference_s is not None else None)
    wrap = "wrap"  # the cause (its unit below it), fit and look-alike columns wrap: no
    # sideways scroll at 1280 px
    rows: list[Row] = [[f"{i + 1}", Cell(join([c.name, tag("div", c.parameter, cls="note")]),
                                         cls=wrap),
                        c.family, f"{c.severity:.4g}", _interval_text(c), f"{c.probability:.2f}",
                        Cell(_fit_text(c), cls=wrap), Cell(_group_text(c, dx.causes), cls=wrap)]
                       for i, c in enumerate(dx.causes[:8])]  # fmt: skip
    head: list[Row] = [["rank", Cell("cause (severity unit)", cls=wrap, header=True), "family",
                        "severity", "95 % interval", "p (relative)", "fit",
                        Cell("cannot be told apart from", cls=wrap, header=True)]]  # fmt: skip
    causes = (table(head, rows, id="causes") if rows else
              para("Nothing ranked: no alarm." if dx.alarm is None else
                   "Nothing ranked: too little of the record after the alarm."))  # fmt: skip
    grown: list[Row] = [[ln.name, f"{ln.freq_hz:.2f}", ln.channel, f"{100 * ln.before:.4f}",
                         f"{100 * ln.after:.4f}", Cell(", ".join(ln.elements), cls=wrap)]
                        for ln in dx.lines]  # fmt: skip
    lines = (table([["line", "Hz", "channel", "before %", "after %", "elements"]], grown,
                   id="lines")
             if dx.lines else para("No kinematic line grew after the change."))  # fmt: skip
    suspect, group = _suspects(dx, train)
    paused = bool(dx.not_steady_s())  # blocks not judged: named in the captions
    body = join([
        tag("h1", title), para(str(info.get("data", "")), cls="sub"), verdict,
        join([para(f"Note: {n}.", cls="note") for n in info.get("notes") or []]),
        section("sliver", "What the sliver says", diagnosis_section(*sliver))
        if sliver is not None else "",
        section("ranked", "Ranked causes", causes, para(
            "Causes in one group move the measured channels the same way: with roller and motor "
            "speeds alone they cannot be told apart (only their severities differ). Gear wear and "
            "chain elongation are ranked from the rollers' angle lags (the driven roller trails "
            "by a fixed angle); gear cracks and run-out and roller run-out leave speeds and "
            "angles unchanged and are not ranked.", cls="note")),
        section("timeline", "Residual timeline", figure(timeline_png(dx), "fig-timeline",
                "Stream levels and angle lags against the record's baseline; below, the statistic "
                "of the rule that raised the alarm over its own limit (for a lag jump or a sensor "
                "rule the CUSUMs, which did not fire, in grey); the alarm in red, the estimated "
                "change shaded" + ("; shaded grey: not judged (a start, a stop or a speed "
                "change)" if paused else "") + ".", "residual timeline")),
        section("spectrum", "Spectrum after the change" if dx.alarm is not None else
                "Residual spectrum", figure(spectrum_png(dx, train, series), "fig-spectrum",
                "Relative residual spectra of each channel " + (
                    "after the alarm" if dx.alarm is not None else "over the record")
                + (", its longest steady stretch" if paused else "") + ".",
                "spectrum"), lines),
        section("train", "Drive train", figure(train_png(train, suspect, group), "fig-train",
                "The suspected element in red, the elements it cannot be told apart from in orange.",
                "drive train")),
        section("settings", "Detector", detector_table(info)),
    ])  # fmt: skip
    return page(title, body)
