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
from scipy.signal import welch  # noqa: E402

from drafttwin import ROLLERS  # noqa: E402

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


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def grid_losses(grid: Mapping[str, Sequence[Mapping]]) -> bytes:
    """Fig. 7 analogue: validation loss of every (lr, hidden, layers) per network."""
    nets = list(grid)
    fig, axes = plt.subplots(1, len(nets), figsize=(6.5 * len(nets), 3.8), squeeze=False)
    for ax, net in zip(axes[0], nets, strict=True):
        rows = list(grid[net])
        lrs = sorted({r["lr"] for r in rows})
        combos = sorted({(r["hidden"], r["layers"]) for r in rows})
        width = 0.8 / len(lrs)
        for k, lr in enumerate(lrs):
            vals = [next((r["val_loss"] for r in rows if r["lr"] == lr and (r["hidden"], r["layers"]) == c),
                         np.nan) for c in combos]  # fmt: skip
            ax.bar(np.arange(len(combos)) + k * width, vals, width, label=f"lr {lr:g}")
        best = min(rows, key=lambda r: r["val_loss"])
        ax.set_xticks(np.arange(len(combos)) + 0.4 - width / 2)
        ax.set_xticklabels([f"h{h}\nL{nl}" for h, nl in combos])
        ax.set_yscale("log")
        ax.set_ylabel("validation loss (MSE, scaled)")
        ax.set_title(f"{net.upper()}: best lr {best['lr']:g}, hidden {best['hidden']}, "
                     f"layers {best['layers']}")  # fmt: skip
        ax.legend(fontsize=8)
    return _png(fig)


def predictions(
    time_s: np.ndarray,
    measured: np.ndarray,
    preds: Mapping[str, np.ndarray],
    zoom_s: tuple[float, float],
    true: np.ndarray | None = None,
) -> bytes:
    """Fig. 8 analogue: measured vs predicted speed per roller, whole test part and a zoom."""
    fig, axes = plt.subplots(len(ROLLERS), 2, figsize=(13, 2.4 * len(ROLLERS)),
                             gridspec_kw={"width_ratios": [2, 1]})  # fmt: skip
    zoom = (time_s >= zoom_s[0]) & (time_s <= zoom_s[1])
    for j, roller in enumerate(ROLLERS):
        for col, mask in ((0, slice(None)), (1, zoom)):
            ax = axes[j, col]
            ax.plot(
                time_s[mask], measured[mask, j], color=COLORS["measured"], lw=0.8, label="measured"
            )
            if true is not None and col == 1:
                ax.plot(
                    time_s[mask], true[mask, j], color=COLORS["true"], lw=0.8, ls=":", label="true"
                )
            for name, p in preds.items():
                ax.plot(time_s[mask], p[mask, j], color=COLORS.get(name), lw=0.8, label=name)
            ax.set_ylabel(f"{roller} (rpm)")
            if j == 0:
                ax.set_title("test part" if col == 0 else f"zoom {zoom_s[0]:.1f}-{zoom_s[1]:.1f} s")
    axes[0, 1].legend(fontsize=7, ncol=2, loc="upper right")
    axes[-1, 0].set_xlabel("time (s)")
    axes[-1, 1].set_xlabel("time (s)")
    fig.tight_layout()
    return _png(fig)


def residuals(time_s: np.ndarray, resid: Mapping[str, np.ndarray], rate_hz: float) -> bytes:
    """Residual time series (measured - predicted) and their spectra (Welch), per roller."""
    fig, axes = plt.subplots(len(ROLLERS), 2, figsize=(13, 2.3 * len(ROLLERS)))
    for j, roller in enumerate(ROLLERS):
        for name, r in resid.items():
            x = r[:, j]
            ok = np.isfinite(x)
            axes[j, 0].plot(time_s[ok], x[ok], lw=0.6, color=COLORS.get(name), label=name)
            if ok.sum() > 64:
                f, p = welch(x[ok] - x[ok].mean(), fs=rate_hz, nperseg=min(1024, ok.sum() // 2))
                axes[j, 1].semilogy(f[1:], p[1:], lw=0.8, color=COLORS.get(name), label=name)
        axes[j, 0].set_ylabel(f"{roller} residual (rpm)")
        axes[j, 1].set_ylabel("PSD (rpm²/Hz)")
    axes[0, 0].legend(fontsize=7, ncol=3)
    axes[-1, 0].set_xlabel("time (s)")
    axes[-1, 1].set_xlabel("frequency (Hz)")
    fig.tight_layout()
    return _png(fig)


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
        ax.set_ylabel("accuracy (%)" if j == 0 else "")
        inset = ax.twinx()
        inset.plot(
            range(len(variants)), paper_means[roller], "kx", ms=7, label="paper (right axis)"
        )
        inset.tick_params(labelsize=7)
        if j == len(ROLLERS) - 1:
            inset.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    return _png(fig)
