"""Report figures (matplotlib, Agg), returned as PNG bytes for embedding.

Each function takes plain arrays and dictionaries, so the figures can be redrawn from
``results.json`` and the CSV tables alone.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter  # noqa: E402
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


def _png_with_legend_on_top(fig: Figure, legend_from: Axes, top: float = 0.965) -> bytes:
    """The figure as PNG with one row of legend above the axes (the entries of
    ``legend_from``); the axes fill the figure up to ``top`` (a fraction of its height)."""
    handles, labels = legend_from.get_legend_handles_labels()
    fig.tight_layout(rect=(0, 0, 1, top))
    fig.legend(handles, labels, loc="upper center", ncol=len(labels), fontsize=8, frameon=False)
    return _png(fig)


def _log_axis_plain(axis) -> None:
    """Log axis ticks at 1, 1.5, 2, 3, 5, 7 × 10^k written as plain numbers."""
    axis.set_major_locator(LogLocator(base=10, subs=(1.0, 1.5, 2.0, 3.0, 5.0, 7.0)))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(NullFormatter())


def grid_losses(grid: Mapping[str, Sequence[Mapping]]) -> bytes:
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
        _log_axis_plain(ax.yaxis)
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
    accuracy: Mapping[str, np.ndarray], paper_means: Mapping[str, Sequence[float]]
) -> bytes:
    """Table 3 analogue: accuracy of each variant over the repeated tests, per roller."""
    variants = list(accuracy)
    fig, axes = plt.subplots(1, len(ROLLERS), figsize=(13, 3.4), sharey=False)
    for j, roller in enumerate(ROLLERS):
        ax = axes[j]
        for k, v in enumerate(variants):
            vals = np.asarray(accuracy[v])[:, j]
            ax.scatter(np.full(len(vals), k) + np.linspace(-0.15, 0.15, len(vals)), vals, s=12,
                       color=COLORS.get(v), label="ours" if k == 0 else None)  # fmt: skip
            ax.hlines(np.mean(vals), k - 0.3, k + 0.3, color="black", lw=1)
        ax.set_xticks(range(len(variants)))
        ax.set_xticklabels(variants)
        ax.set_title(roller)
        ax.set_ylabel("ours: accuracy (%)" if j == 0 else "")
        ax.ticklabel_format(axis="y", useOffset=False)
        inset = ax.twinx()
        inset.plot(
            range(len(variants)), paper_means[roller], "kx", ms=7, label="paper mean (right axis)"
        )
        inset.tick_params(labelsize=7, colors="#6b5f45")
        inset.ticklabel_format(axis="y", useOffset=False)
        if j == len(ROLLERS) - 1:
            inset.set_ylabel("paper: accuracy (%)", color="#6b5f45")
            inset.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    return _png(fig)


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
        _log_axis_plain(ax.xaxis)
        ax.grid(axis="x", which="major", color="#e5e5e5", lw=0.6)
        ax.set_yticks(y)
        ax.set_yticklabels(models)
        ax.set_ylim(-0.6, len(models) - 0.4)
        ax.set_title(roller)
        ax.set_xlabel(with_unit("RMSE", unit))
    return _png_with_legend_on_top(fig, axes[0], top=0.9)
