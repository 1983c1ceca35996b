"""Report figures (matplotlib, Agg), returned as PNG bytes for embedding.

Each function takes plain arrays and dictionaries, so the figures can be redrawn from
``results.json`` and the CSV tables alone.
"""

from __future__ import annotations

import io
import math
from collections.abc import Mapping, Sequence
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.axis import Axis  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.ticker import FuncFormatter, LogLocator, MaxNLocator, NullFormatter  # noqa: E402
from scipy.signal import welch  # noqa: E402

from drafttwin._constants import ROLLERS  # noqa: E402
from drafttwin.report.fmt import with_unit  # noqa: E402

COLORS = {
    "measured": "#222222",
    "true": "#999999",
    "mechanistic": "#d62728",
    "persistence": "#7f7f7f",
    "gru": "#1f77b4",
    "lstm": "#17becf",
    "parallel": "#ff7f0e",
    "md-s-l": "#2ca02c",
    "md-s-l+d": "#98df8a",
    "md-l": "#9467bd",
    "md-s": "#8c564b",
}


def _png(fig: Figure) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def _png_with_legend_on_top(
    fig: Figure, legend_from: Axes | Sequence[Axes], top: float = 0.965
) -> bytes:
    """The figure as PNG with one row of legend above the axes (the entries of
    ``legend_from``); the axes fill the figure up to ``top`` (a fraction of its height)."""
    handles, labels = [], []
    for ax in [legend_from] if isinstance(legend_from, Axes) else legend_from:
        h, lab = ax.get_legend_handles_labels()
        handles += h
        labels += lab
    fig.tight_layout(rect=(0, 0, 1, top))
    fig.legend(handles, labels, loc="upper center", ncol=len(labels), fontsize=8, frameon=False)
    return _png(fig)


class _PlainLogLocator(LogLocator):
    """:class:`LogLocator` that, on a span holding fewer than two of its ticks, gives at most
    four evenly spaced ones (matplotlib's own fallback put one every 2.5 % of a narrow span,
    labels run together)."""

    def __init__(self, subs: tuple[float, ...]) -> None:
        super().__init__(base=10, subs=subs)
        self.plain_subs = subs

    def tick_values(self, vmin: float, vmax: float) -> Any:
        lo, hi = min(vmin, vmax), max(vmin, vmax)
        if lo > 0:
            decades = range(math.floor(math.log10(lo)), math.ceil(math.log10(hi)) + 1)
            own = [s * 10.0**k for k in decades for s in self.plain_subs]
            if sum(lo <= t <= hi for t in own) < 2:
                return MaxNLocator(nbins=3, steps=[1, 2, 2.5, 5, 10]).tick_values(lo, hi)
        return super().tick_values(vmin, vmax)


def log_axis_plain(axis: Axis, sparse: bool = False) -> None:
    """Log axis ticks at 1, 1.5, 2, 3, 5, 7 × 10^k (``sparse``: 1, 2, 5 × 10^k) written as
    plain numbers (a few evenly spaced ones on a span narrower than that)."""
    subs = (1.0, 2.0, 5.0) if sparse else (1.0, 1.5, 2.0, 3.0, 5.0, 7.0)
    axis.set_major_locator(_PlainLogLocator(subs))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(NullFormatter())


def grid_losses(grid: Mapping[str, Sequence[Mapping[str, Any]]]) -> bytes:
    """Fig. 7 analogue: validation loss of every (lr, hidden, layers) per network.

    One line per learning rate over the (hidden, layers) combinations, log scale; the best
    configuration (lowest finite loss) is ringed.
    """
    nets = list(grid)
    fig, axes = plt.subplots(1, len(nets), figsize=(6.5 * len(nets), 3.8), squeeze=False)
    for ax, net in zip(axes[0], nets, strict=True):
        rows = list(grid[net])
        lrs = sorted({r["lr"] for r in rows})
        combos = sorted({(r["hidden"], r["layers"]) for r in rows})
        x = np.arange(len(combos))
        for lr in lrs:
            vals = [next((r["val_loss"] for r in rows if r["lr"] == lr and (r["hidden"], r["layers"]) == c),
                         np.nan) for c in combos]  # fmt: skip
            ax.plot(x, np.asarray(vals, dtype=float), "o-", ms=5, lw=1, label=f"lr {lr:g}")
        finite = [r for r in rows if np.isfinite(r["val_loss"])]
        ax.set_xticks(x)
        ax.set_xticklabels([f"h{h}\nL{nl}" for h, nl in combos])
        ax.set_yscale("log")
        log_axis_plain(ax.yaxis)
        ax.grid(axis="y", which="major", color="#e5e5e5", lw=0.6)
        ax.set_ylabel("validation loss (MSE, scaled)")
        if finite:
            best = min(finite, key=lambda r: r["val_loss"])
            ax.plot([combos.index((best["hidden"], best["layers"]))], [best["val_loss"]], "o",
                    ms=13, mfc="none", mec="black", label="best")  # fmt: skip
            ax.set_title(f"{net.upper()}: best lr {best['lr']:g}, hidden {best['hidden']}, "
                         f"layers {best['layers']}")  # fmt: skip
        ax.legend(fontsize=8)
    fig.tight_layout()
    return _png(fig)


def predictions(
    time_s: np.ndarray,
    measured: np.ndarray,
    preds: Mapping[str, np.ndarray],
    zoom_s: tuple[float, float],
    true: np.ndarray | None = None,
    unit: str = "",
) -> bytes:
    """Fig. 8 analogue: measured vs predicted speed per roller, whole test part and a zoom;
    ``unit`` labels the axes."""
    fig, axes = plt.subplots(len(ROLLERS), 2, figsize=(13, 2.4 * len(ROLLERS)),
                             gridspec_kw={"width_ratios": [2, 1]})  # fmt: skip
    zoom = (time_s >= zoom_s[0]) & (time_s <= zoom_s[1])
    for j, roller in enumerate(ROLLERS):
        for col, mask in ((0, slice(None)), (1, zoom)):
            ax = axes[j, col]
            lw = 0.5 if col == 0 else 0.9
            ax.plot(time_s[mask], measured[mask, j], color=COLORS["measured"], lw=lw,
                    label="measured")  # fmt: skip
            if true is not None and col == 1:
                ax.plot(time_s[mask], true[mask, j], color=COLORS["true"], lw=1.2, ls=":",
                        label="true")  # fmt: skip
            for name, p in preds.items():
                ax.plot(time_s[mask], p[mask, j], color=COLORS.get(name), lw=lw, alpha=0.85,
                        label=name)  # fmt: skip
            ax.set_ylabel(with_unit(roller, unit))
            ax.ticklabel_format(axis="y", useOffset=False)
            if j == 0:
                ax.set_title("test part" if col == 0 else f"zoom {zoom_s[0]:.1f}-{zoom_s[1]:.1f} s")
    axes[-1, 0].set_xlabel("time (s)")
    axes[-1, 1].set_xlabel("time (s)")
    return _png_with_legend_on_top(fig, axes[0, 1])


def residuals(
    time_s: np.ndarray, resid: Mapping[str, np.ndarray], rate_hz: float, unit: str = ""
) -> bytes:
    """Residual time series (measured - predicted) and their spectra (Welch), per roller;
    ``unit`` labels the axes."""
    fig, axes = plt.subplots(len(ROLLERS), 2, figsize=(13, 2.3 * len(ROLLERS)))
    for j, roller in enumerate(ROLLERS):
        for name, r in resid.items():
            x = r[:, j]
            ok = np.isfinite(x)
            axes[j, 0].plot(time_s[ok], x[ok], lw=0.6, color=COLORS.get(name), label=name)
            if ok.sum() > 64:
                f, p = welch(x[ok] - x[ok].mean(), fs=rate_hz, nperseg=min(1024, ok.sum() // 2))
                axes[j, 1].semilogy(f[1:], p[1:], lw=0.8, color=COLORS.get(name), label=name)
        axes[j, 0].set_ylabel(with_unit(f"{roller} residual", unit))
        axes[j, 1].set_ylabel(with_unit("PSD", f"{unit}²/Hz" if unit else ""))
    axes[-1, 0].set_xlabel("time (s)")
    axes[-1, 1].set_xlabel("frequency (Hz)")
    return _png_with_legend_on_top(fig, axes[0, 0])


def ablation_spread(
    accuracy: Mapping[str, np.ndarray],
    paper_means: Mapping[str, Sequence[float]],
    labels: Mapping[str, str] | None = None,
) -> bytes:
    """Table 3 analogue: accuracy of each variant in each repeated test (dots) and their mean
    ± one standard deviation (bar), per roller; the paper's means on a second axis (its own
    scale). ``labels`` gives the variants' display names."""
    variants = list(accuracy)
    fig, axes = plt.subplots(1, len(ROLLERS), figsize=(13, 3.6))
    insets = []
    for j, roller in enumerate(ROLLERS):
        ax = axes[j]
        for k, v in enumerate(variants):
            _repeats(ax, k, np.asarray(accuracy[v], dtype=float)[:, j], COLORS.get(v), k == 0)
        ax.set_xticks(range(len(variants)), [(labels or {}).get(v, v) for v in variants])
        ax.set_xlim(-0.5, len(variants) - 0.5)
        ax.set_title(f"{roller} roller", fontsize=10)
        ax.set_ylabel("ours: accuracy (%)" if j == 0 else "")
        ax.ticklabel_format(axis="y", useOffset=False)
        inset = ax.twinx()
        inset.plot(range(len(variants)), paper_means[roller], "kx", ms=7,
                   label="paper: mean of its 10 tests (right axis)")  # fmt: skip
        inset.tick_params(labelsize=7, colors="#6b5f45")
        inset.ticklabel_format(axis="y", useOffset=False)
        insets.append(inset)
    insets[-1].set_ylabel("paper: accuracy (%)", color="#6b5f45")
    return _png_with_legend_on_top(fig, [axes[0], insets[0]], top=0.9)


def _repeats(ax: Axes, k: int, vals: np.ndarray, color: str | None, legend: bool) -> None:
    """One variant's repeats at x = k: the dots, and the mean ± std as a bar beside them."""
    ax.scatter(k - 0.1 + np.linspace(-0.12, 0.12, len(vals)), vals, s=12, color=color,
               label="ours: each repeated test" if legend else None)  # fmt: skip
    std = float(np.std(vals, ddof=1)) if len(vals) > 1 else 0.0
    ax.errorbar([k + 0.2], [float(np.mean(vals))], yerr=[std], fmt="_", ms=12, capsize=4,
                color="black", lw=1.2, label="ours: mean ± std" if legend else None)  # fmt: skip


def rmse_overview(
    rmse: Mapping[str, Sequence[float]],
    rmse_true: Mapping[str, Sequence[float]],
    floor: Sequence[float],
    sensor: Sequence[float],
    unit: str = "",
) -> bytes:
    """RMSE per model and roller vs the measured (filled dot) and the true speed (open dot).

    ``rmse`` and ``rmse_true`` map a model name to its four per-roller values (in ``unit``);
    ``floor`` holds the four one-step floors of the measured speed (dashed line) and ``sensor``
    the encoders' own errors, measured vs true (dotted line; NaN where unknown). Log
    scale, one panel per roller, models top to bottom in the given order.
    """
    models = list(rmse)
    y = np.arange(len(models))[::-1]
    fig, axes = plt.subplots(1, len(ROLLERS), figsize=(13, 0.45 * len(models) + 1.2), sharey=True)
    for j, roller in enumerate(ROLLERS):
        ax = axes[j]
        for k, m in enumerate(models):
            c = COLORS.get(m, "#444444")
            ax.plot(
                [rmse[m][j]], [y[k]], "o", color=c, ms=7, label="vs measured" if k == 0 else None
            )
            t = rmse_true.get(m, [np.nan] * len(ROLLERS))[j]
            ax.plot([t], [y[k]], "o", mfc="white", mec=c, ms=7, label="vs true" if k == 0 else None)
        if np.isfinite(floor[j]):
            ax.axvline(floor[j], color="black", ls="--", lw=1, label="floor (vs measured)")
        if np.isfinite(sensor[j]):
            ax.axvline(sensor[j], color="black", ls=":", lw=1, label="encoder error")
        ax.set_xscale("log")
        log_axis_plain(ax.xaxis)
        ax.grid(axis="x", which="major", color="#e5e5e5", lw=0.6)
        ax.set_yticks(y)
        ax.set_yticklabels(models)
        ax.set_ylim(-0.6, len(models) - 0.4)
        ax.set_title(roller)
        ax.set_xlabel(with_unit("RMSE", unit))
    return _png_with_legend_on_top(fig, axes[0], top=0.9)


REFERENCE_STYLE = {
    "floor": {"color": "black", "ls": "--", "lw": 1.1},
    "persistence": {"color": COLORS["persistence"], "ls": "-", "lw": 1.6, "alpha": 0.7},
    "physics": {"color": COLORS["mechanistic"], "ls": "-.", "lw": 1.3},
}


def headline_rmse(
    rmse: Mapping[str, Sequence[float]],
    references: Mapping[str, Sequence[float]],
    notes: Mapping[str, Sequence[str]],
    colors: Mapping[str, str | None],
    unit: str = "",
) -> bytes:
    """The report's first figure: each model's test RMSE per roller (a dot; log scale), a note
    beside each dot (the paper's rank), and reference lines per roller.

    ``rmse`` maps a model's display name to its four per-roller values; ``references`` maps a
    reference's display name to four values, drawn as vertical lines (style from
    :data:`REFERENCE_STYLE` by its first word; NaN: not drawn); ``notes`` maps a model's
    display name to four short texts, ``colors`` to its colour.
    """
    models = list(rmse)
    y = np.arange(len(models))[::-1]
    fig, axes = plt.subplots(1, len(ROLLERS), figsize=(12, 0.42 * len(models) + 1.45), sharey=True)
    for j, roller in enumerate(ROLLERS):
        ax = axes[j]
        for name, values in references.items():
            if np.isfinite(values[j]):
                style = REFERENCE_STYLE.get(name.split()[0], {"color": "#444444"})
                ax.axvline(values[j], label=name, **style)
        for k, m in enumerate(models):
            if not np.isfinite(rmse[m][j]):
                continue
            ax.plot([rmse[m][j]], [y[k]], "o", ms=8, color=colors.get(m), zorder=3)
            ax.annotate(notes.get(m, [""] * len(ROLLERS))[j], (rmse[m][j], y[k]),
                        xytext=(0, 8), textcoords="offset points", ha="center", fontsize=7.5,
                        color="#6b5f45")  # fmt: skip
        ax.set_xscale("log")
        log_axis_plain(ax.xaxis)
        ax.margins(x=0.12)
        ax.grid(axis="x", which="major", color="#e5e5e5", lw=0.6)
        ax.set_yticks(y, models)
        ax.set_ylim(-0.5, len(models) - 0.2)
        ax.set_title(f"{roller} roller", fontsize=10)
        ax.set_xlabel(with_unit("test RMSE", unit), fontsize=9)
    return _png_with_legend_on_top(fig, axes[0], top=0.93)


def speed_change(
    curves: Mapping[str, Mapping[str, Sequence[tuple[float, float]]]],
    colors: Mapping[str, str | None],
    unit: str = "",
) -> bytes:
    """RMSE against the speed change from the training point (%), one panel per task, one
    line per model, log scale; ``curves`` maps a task's title to ``{model: [(pct, rmse)]}``."""
    fig, axes = plt.subplots(1, len(curves), figsize=(12, 3.6), squeeze=False)
    for ax, (title, by_model) in zip(axes[0], curves.items(), strict=True):
        for model, points in by_model.items():
            pts = sorted(points)
            ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", ms=5, lw=1.3,
                    color=colors.get(model), label=model)  # fmt: skip
        ax.axvline(0.0, color="#999999", ls=":", lw=1)
        ax.annotate("trained here", (0.0, 1.0), xycoords=("data", "axes fraction"), xytext=(3, -10),
                    textcoords="offset points", fontsize=7.5, color="#777777")  # fmt: skip
        ax.set_yscale("log")
        low, high = ax.get_ylim()
        log_axis_plain(ax.yaxis, sparse=high > 20 * low)
        ax.grid(axis="y", which="major", color="#e5e5e5", lw=0.6)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("speed change from the training point (%)")
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:+.0f}" if v else "0"))
        ax.set_ylabel(with_unit("RMSE, mean over rollers", unit))
    return _png_with_legend_on_top(fig, axes[0][0], top=0.9)
