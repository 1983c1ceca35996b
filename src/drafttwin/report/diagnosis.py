"""The diagnosis page a maintenance engineer reads: alarm, ranked causes, evidence.

Three figures: the residual timeline with the CUSUM statistics and the alarm; the spectrum
after the change with every kinematic line marked (the implicated ones in red); the drive
train with the suspected element highlighted (its non-separable group in orange).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from drafttwin.data.series import MeasurementSeries  # noqa: E402
from drafttwin.diagnosis.detect import STREAMS, stream_matrix  # noqa: E402
from drafttwin.diagnosis.diagnose import Diagnosis  # noqa: E402
from drafttwin.diagnosis.residuals import CHANNELS  # noqa: E402
from drafttwin.diagnosis.spectrum import kinematic_lines, residual_samples, spectrum  # noqa: E402
from drafttwin.mechanics import DriveTrain  # noqa: E402
from drafttwin.report.figures import _png  # noqa: E402
from drafttwin.report.html import (  # noqa: E402
    Cell,
    Row,
    figure,
    join,
    kv_table,
    page,
    para,
    section,
    table,
    tag,
)

RED, ORANGE, GREY = "#d62728", "#ff9f1c", "#b0b7c3"


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
    bx.plot(f.time_s, det.statistic.max(axis=1), color="#1f5f8b", lw=1, label="max CUSUM / h")
    bx.axhline(1.0, color="k", ls="--", lw=0.8, label="threshold")
    bx.set_ylabel("CUSUM / threshold")
    bx.set_xlabel("time, s")
    if dx.alarm is not None:
        for a in (ax, lx, bx):
            a.axvline(dx.alarm.time_s, color=RED, lw=1.5)
            a.axvspan(dx.alarm.change_s, dx.alarm.time_s, color=RED, alpha=0.1)
    bx.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    return _png(fig)


def spectrum_png(dx: Diagnosis, train: DriveTrain, series: MeasurementSeries) -> bytes:
    rate = series.sample_rate_hz
    r = residual_samples(series)
    start = dx.alarm.time_s if dx.alarm is not None else 0.0
    after = r[series.time_s > start]
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
        ax.text((depth[e.parent] + depth[e.child]) / 2, (row[e.parent] + row[e.child]) / 2 + 0.15,
                e.coupling.name, fontsize=7, ha="center", color=c if c != GREY else "k")  # fmt: skip
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
    group = {where(n.split(":")[0], top.family) for n in top.group}
    return suspect, group - suspect


def render_diagnosis(dx: Diagnosis, train: DriveTrain, series: MeasurementSeries,
                     info: Mapping[str, Any], title: str = "Fault diagnosis") -> str:  # fmt: skip
    """The whole self-contained page."""
    a = dx.alarm
    if a is None:
        verdict = para(
            "No alarm: the residuals stayed within the thresholds set from healthy data."
        )
    else:
        top = dx.causes[0] if dx.causes else None
        what = (f"most likely {top.element}:{top.kind} ({top.family}), severity {top.severity:.4g} "
                f"[{top.interval[0]:.3g}, {top.interval[1]:.3g}] {top.parameter}"
                if top else "no candidate evaluated")  # fmt: skip
        verdict = tag("div", join([tag("strong", f"Alarm at {a.time_s:.1f} s ({a.test}); change "
                                              f"estimated at {a.change_s:.1f} s: {what}.")]),
                      cls="banner")  # fmt: skip
    wrap = "wrap"  # the unit and look-alike columns wrap: no sideways scroll at 1280 px
    rows: list[Row] = [[f"{i + 1}", c.name, c.family, f"{c.severity:.4g}",
                        f"[{c.interval[0]:.3g}, {c.interval[1]:.3g}]", Cell(c.parameter, cls=wrap),
                        f"{c.probability:.2f}", Cell(", ".join(c.group) or "-", cls=wrap)]
                       for i, c in enumerate(dx.causes[:8])]  # fmt: skip
    head: list[Row] = [["rank", "cause", "family", "severity", "95 % interval",
                        Cell("unit", cls=wrap, header=True), "probability",
                        Cell("cannot be told apart from", cls=wrap, header=True)]]  # fmt: skip
    causes = table(head, rows, id="causes")
    grown: list[Row] = [[ln.name, f"{ln.freq_hz:.2f}", ln.channel, f"{100 * ln.before:.4f}",
                         f"{100 * ln.after:.4f}", Cell(", ".join(ln.elements), cls=wrap)]
                        for ln in dx.lines]  # fmt: skip
    lines = (table([["line", "Hz", "channel", "before %", "after %", "elements"]], grown,
                   id="lines")
             if dx.lines else para("No kinematic line grew after the change."))  # fmt: skip
    suspect, group = _suspects(dx, train)
    body = join([
        tag("h1", title), para(str(info.get("data", "")), cls="sub"), verdict,
        section("ranked", "Ranked causes", causes, para(
            "Causes in one group move the measured channels the same way: with roller and motor "
            "speeds alone they cannot be told apart (only their severities differ). Gear wear and "
            "chain elongation are ranked from the rollers' angle lags (the driven roller trails "
            "by a fixed angle); gear cracks and run-out and roller run-out leave speeds and "
            "angles unchanged and are not ranked.", cls="note")),
        section("timeline", "Residual timeline", figure(timeline_png(dx), "fig-timeline",
                "Stream levels against the record's baseline, and the largest CUSUM statistic over "
                "its threshold; the alarm in red, the estimated change shaded.", "residual timeline")),
        section("spectrum", "Spectrum after the change", figure(spectrum_png(dx, train, series),
                "fig-spectrum", "Relative residual spectra of each channel after the alarm.",
                "spectrum"), lines),
        section("train", "Drive train", figure(train_png(train, suspect, group), "fig-train",
                "The suspected element in red, the elements it cannot be told apart from in orange.",
                "drive train")),
        section("settings", "Detector", kv_table({k: v for k, v in info.items() if k != "data"})),
    ])  # fmt: skip
    return page(title, body)
