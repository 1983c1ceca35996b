"""Samples that alone set a channel's range: a glitch the one-sample spike rule does not take
out (two or more equal wrong samples, a spike on a record edge) survives preprocessing, and the
networks, which scale each channel min-max over its training range, then see the channel
squeezed into a sliver of their input range and learn it poorly (one such sample, 509 rpm on a
434-rpm roller, made every learned model's second roller worse than its physics:
docs/data.md)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

STRETCH_LIMIT = 5.0
"""A channel's range is *stretched* when it is more than this many times the range of all but
its most extreme samples (:func:`range_stretchers`)."""
TRIM_SHARE = 1e-4
"""The share of a channel's samples left out on each side for its core range (at least
:data:`TRIM_MIN` each side): a start-up or a step holds far more samples than that."""
TRIM_MIN = 2


def range_stretchers(
    values: np.ndarray, time_s: np.ndarray, channels: Sequence[str]
) -> dict[str, dict[str, float]]:
    """Per channel whose range is stretched (more than :data:`STRETCH_LIMIT` times the range
    without its ``k`` lowest and ``k`` highest samples, ``k = max(2, 1e-4 n)``): the farthest
    sample from that core range (``value``, ``time_s``), the core range (``core_low``,
    ``core_high``) and the ratio. Channels with a flat core or too few samples are skipped."""
    out: dict[str, dict[str, float]] = {}
    for j, name in enumerate(channels):
        x = np.asarray(values[:, j], dtype=np.float64)
        ok = np.flatnonzero(np.isfinite(x))
        k = max(TRIM_MIN, math.ceil(TRIM_SHARE * ok.size))
        if ok.size < 10 * k:
            continue
        ranked = np.sort(x[ok])
        low, high = float(ranked[k]), float(ranked[-k - 1])
        core, full = high - low, float(ranked[-1] - ranked[0])
        if core <= 0 or full <= STRETCH_LIMIT * core:
            continue
        gap = np.maximum(low - x[ok], x[ok] - high)
        i = int(ok[np.argmax(gap)])
        out[name] = {"value": float(x[i]), "time_s": float(time_s[i]), "core_low": low,
                     "core_high": high, "ratio": full / core}  # fmt: skip
    return out


def describe(channel: str, found: dict[str, float], unit: str = "") -> str:
    """One :func:`range_stretchers` finding in words: ``second spans 36x the range its other
    samples keep to (433.2 to 435.6 rpm): 520 rpm at 20.01 s``."""
    u = f" {unit}" if unit else ""
    return (f"{channel} spans {found['ratio']:.0f}x the range its other samples keep to "
            f"({found['core_low']:.6g} to {found['core_high']:.6g}{u}): {found['value']:.6g}{u} "
            f"at {found['time_s']:.6g} s")  # fmt: skip
