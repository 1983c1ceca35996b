"""The paper's preprocessing: interpolation of missing samples, outlier smoothing, split.

Policies (see ``docs/data.md``):

* **Missing samples** (``NaN``) are filled by linear interpolation between the nearest valid
  samples before and after (paper eq. 12, ``x(t+i) = x(t) + i (x(t+j) - x(t)) / j``), on the
  sample index (the reader puts every file on a regular grid, so index = time).
* **Leading / trailing gaps** have only one valid neighbour; they take the nearest valid value
  (the paper's "adjacent values" for gaps interpolation cannot bridge).
* **Long gaps**: with ``max_gap=None`` (default, the paper) every gap is filled. With
  ``max_gap=k`` a run of more than ``k`` missing samples (interior or at an edge) is left
  ``NaN`` and counted in the report, because interpolating across it would invent data.
* **Outliers**: a sample is an outlier when it differs from *both* neighbours by more than
  ``threshold`` (relative to each neighbour's magnitude) *in the same direction*, i.e. it is
  a one-sample spike. "Both" rather than the paper's "either": with "either", the two samples
  next to a spike, and both sides of every genuine step change, would be flagged too. The
  first and last samples (one neighbour) and samples next to a missing value are never
  flagged. An outlier is replaced by the mean of its neighbours (paper); a run of adjacent
  outliers (alternating spikes) is interpolated between its nearest good neighbours. Bursts
  of two or more equal wrong samples are not one-sample spikes and are not detected.
* **Order**: interpolation first, then smoothing (the paper's order), on each roller.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import DataError


def nan_runs(missing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start indices and lengths of the runs of ``True`` in a 1-D boolean array."""
    edges = np.diff(np.concatenate(([0], missing.astype(np.int8), [0])))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1)
    return starts, ends - starts


def _fill_column(x: np.ndarray, max_gap: int | None) -> np.ndarray:
    """One column with its gaps filled (eq. 12; edges: nearest value); long gaps kept NaN."""
    missing = np.isnan(x)
    good = np.flatnonzero(~missing)
    if good.shape[0] == 0 or good.shape[0] == x.shape[0]:
        return x.copy()
    out = x.copy()
    todo = np.flatnonzero(missing)
    out[todo] = np.interp(todo, good, x[good])  # np.interp holds the edge values outside
    if max_gap is not None:
        starts, lengths = nan_runs(missing)
        long = lengths > max_gap
        if long.any():
            keep = np.repeat(long, lengths)  # one flag per missing sample, in order
            out[todo[keep]] = np.nan
    return out


def interpolate_missing(
    rpm: np.ndarray, max_gap: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Fill missing samples (``NaN``) by linear interpolation (paper eq. 12).

    Args:
        rpm: speeds, shape ``(n,)`` or ``(n, k)``, rpm.
        max_gap: the longest run of missing samples to fill (samples); longer runs stay
            ``NaN``. ``None`` fills every gap. Leading and trailing gaps take the nearest
            valid value. A column without any valid sample stays ``NaN``.

    Returns:
        ``(filled, filled_mask)``: the new array (same shape, float64) and a boolean mask of
        the samples that were filled.
    """
    if max_gap is not None and max_gap < 0:
        raise ValueError(f"max_gap must be >= 0 or None, got {max_gap}")
    x = np.asarray(rpm, dtype=np.float64)
    x2 = x.reshape(x.shape[0], -1)
    out = np.column_stack([_fill_column(x2[:, j], max_gap) for j in range(x2.shape[1])])
    out = out.reshape(x.shape)
    return out, np.isnan(x) & ~np.isnan(out)


def find_outliers(rpm: np.ndarray, threshold: float = 0.10) -> np.ndarray:
    """Mask of one-sample spikes: > ``threshold`` (relative) away from both neighbours.

    The deviation from a neighbour ``a`` counts when ``|x - a| > threshold * |a|`` and both
    deviations have the same sign (the sample is above both neighbours or below both).
    """
    x = np.asarray(rpm, dtype=np.float64)
    mask = np.zeros(x.shape, dtype=bool)
    if x.shape[0] < 3:
        return mask
    prev, cur, nxt = x[:-2], x[1:-1], x[2:]
    with np.errstate(over="ignore", invalid="ignore"):
        tol_p, tol_n = threshold * np.abs(prev), threshold * np.abs(nxt)
        up = (cur - prev > tol_p) & (cur - nxt > tol_n)
        down = (prev - cur > tol_p) & (nxt - cur > tol_n)
    mask[1:-1] = up | down
    return mask


def smooth_outliers(rpm: np.ndarray, threshold: float = 0.10) -> tuple[np.ndarray, np.ndarray]:
    """Replace one-sample spikes by the mean of their neighbours (paper's rule, "both" variant).

    Args:
        rpm: speeds, shape ``(n,)`` or ``(n, k)``, rpm; ``NaN`` allowed (never flagged, and a
            sample next to a ``NaN`` is never flagged).
        threshold: relative deviation from each neighbour that makes a spike (0.10 = 10 %).

    Returns:
        ``(smoothed, outlier_mask)``.
    """
    if not threshold >= 0:
        raise ValueError(f"threshold must be >= 0, got {threshold}")
    x = np.asarray(rpm, dtype=np.float64)
    x2 = x.reshape(x.shape[0], -1)
    mask2 = find_outliers(x2, threshold)
    out = x2.copy()
    for j in np.flatnonzero(mask2.any(axis=0)):
        bad = mask2[:, j]
        good = np.flatnonzero(~bad & ~np.isnan(x2[:, j]))
        out[bad, j] = np.interp(np.flatnonzero(bad), good, x2[good, j])
    return out.reshape(x.shape), mask2.reshape(x.shape)


@dataclass
class PreprocessReport:
    """What preprocessing changed, per roller (counts in samples)."""

    rollers: tuple[str, ...]
    missing: np.ndarray  # (n, k) bool: NaN in the input
    filled: np.ndarray  # (n, k) bool: filled by interpolation / edge hold
    outliers: np.ndarray  # (n, k) bool: replaced by the neighbour mean
    max_gap: int | None = None
    threshold: float | None = 0.10  # None: smoothing skipped
    extra: dict[str, int] = field(default_factory=dict)  # motor / set-point samples filled

    @property
    def n_missing(self) -> dict[str, int]:
        return self._count(self.missing)

    @property
    def n_filled(self) -> dict[str, int]:
        return self._count(self.filled)

    @property
    def n_left_missing(self) -> dict[str, int]:
        """Samples still ``NaN`` after preprocessing (gaps longer than ``max_gap``)."""
        return self._count(self.missing & ~self.filled)

    @property
    def n_outliers(self) -> dict[str, int]:
        return self._count(self.outliers)

    def gaps(self) -> dict[str, dict[str, int]]:
        """Per roller: number of runs of missing samples and the longest run (samples)."""
        out = {}
        for j, r in enumerate(self.rollers):
            _, lengths = nan_runs(self.missing[:, j])
            out[r] = {"count": int(lengths.shape[0]), "longest": int(lengths.max(initial=0))}
        return out

    def _count(self, mask: np.ndarray) -> dict[str, int]:
        return {r: int(c) for r, c in zip(self.rollers, mask.sum(axis=0), strict=True)}

    def to_dict(self) -> dict[str, Any]:
        """Counts only (no masks), JSON-ready."""
        return {
            "max_gap": self.max_gap,
            "outlier_threshold": self.threshold,
            "missing": self.n_missing,
            "filled": self.n_filled,
            "left_missing": self.n_left_missing,
            "outliers": self.n_outliers,
            "gaps": self.gaps(),
            "other_channels_filled": dict(self.extra),
        }


def _fill_optional(series: MeasurementSeries, max_gap: int | None) -> tuple[dict, dict]:
    """Motor speed: interpolated like the rollers; set-points: last value held (then first)."""
    counts: dict[str, int] = {}
    changes: dict[str, Any] = {}
    if series.motor_rpm is not None:
        motor, filled = interpolate_missing(series.motor_rpm, max_gap)
        changes["motor_rpm"], counts["motor"] = motor, int(filled.sum())
    inputs = {}
    for name, values in series.inputs.items():
        x = np.asarray(values, dtype=np.float64)
        valid = ~np.isnan(x)
        if valid.all() or not valid.any():
            inputs[name] = x
            continue
        idx = np.maximum.accumulate(np.where(valid, np.arange(x.shape[0]), -1))
        idx[idx < 0] = np.flatnonzero(valid)[0]
        inputs[name], counts[name] = x[idx], int((~valid).sum())
    if inputs:
        changes["inputs"] = inputs
    return changes, counts


def preprocess(
    series: MeasurementSeries,
    *,
    max_gap: int | None = None,
    outlier_threshold: float | None = 0.10,
) -> tuple[MeasurementSeries, PreprocessReport]:
    """Interpolate missing samples, then smooth one-sample outliers (the paper's order).

    Args:
        series: measured speeds (rpm), ``NaN`` = missing.
        max_gap: longest run of missing samples to fill; ``None`` fills all (see module doc).
        outlier_threshold: relative spike threshold (0.10 = the paper's 10 %); ``None`` skips
            outlier smoothing.

    Returns:
        ``(clean series, report)``. The clean series' ``metadata["preprocess"]`` holds the
        report's counts. Motor speed is interpolated like the rollers; set-points hold their
        last value.
    """
    filled_rpm, filled = interpolate_missing(series.values, max_gap)
    if outlier_threshold is None:
        clean, outliers = filled_rpm, np.zeros(filled.shape, dtype=bool)
    else:
        clean, outliers = smooth_outliers(filled_rpm, outlier_threshold)
    changes, extra = _fill_optional(series, max_gap)
    report = PreprocessReport(
        rollers=series.channels,
        missing=np.isnan(series.values),
        filled=filled,
        outliers=outliers,
        max_gap=max_gap,
        threshold=None if outlier_threshold is None else float(outlier_threshold),
        extra=extra,
    )
    metadata = {**series.metadata, "preprocess": report.to_dict()}
    return replace(series, values=clean, metadata=metadata, **changes), report


def chronological_split(
    series: MeasurementSeries, train_fraction: float = 0.7
) -> tuple[MeasurementSeries, MeasurementSeries]:
    """The first ``train_fraction`` of the samples for training, the rest for testing.

    No shuffling: the test part is the later part of the recording (paper: 70 % / 30 %).
    ``n_train = floor(train_fraction * n)``; both parts must hold at least two samples.
    """
    n = len(series)
    if not 0.0 < train_fraction < 1.0:
        raise DataError(
            f"train fraction {train_fraction} is not between 0 and 1",
            source=series.metadata.get("source"),
            where="train_fraction",
            fix="use e.g. 0.7 (70 % training, 30 % test, as the paper)",
        )
    n_train = int(np.floor(train_fraction * n))
    if n_train < 2 or n - n_train < 2:
        raise DataError(
            f"{n} samples are too few to split {train_fraction:g} / {1 - train_fraction:g}",
            source=series.metadata.get("source"),
            where="train_fraction",
            fix="use a longer recording or a train fraction nearer 0.5",
        )
    return series.slice(0, n_train), series.slice(n_train)


def reject_spikes_causal(rpm: np.ndarray, threshold: float = 0.10) -> tuple[np.ndarray, np.ndarray]:
    """Mark as missing (``NaN``) every sample that jumps more than ``threshold`` (relative)
    from the last accepted sample of its column; uses past samples only.

    The paper's outlier rule compares a sample with *both* neighbours, so it needs the next
    sample and cannot clean a model's inputs online. This causal variant can: a spike is
    dropped and the models hold the last value. A genuine speed change of more than
    ``threshold`` within one sample (a start from standstill) would be dropped too, so use it
    on running data. Returns ``(cleaned rpm, rejected mask)``.
    """
    x = np.array(rpm, dtype=np.float64, copy=True)
    squeeze = x.ndim == 1
    x2 = x[:, None] if squeeze else x
    rejected = np.zeros(x2.shape, dtype=bool)
    for j in range(x2.shape[1]):
        last = np.nan
        col = x2[:, j]
        for i in range(col.shape[0]):  # sequential by nature: each decision depends on the last
            v = col[i]
            if np.isnan(v):
                continue
            if np.isfinite(last) and abs(v - last) > threshold * abs(last):
                rejected[i, j] = True
                col[i] = np.nan
            else:
                last = v
    return (x2[:, 0] if squeeze else x2), (rejected[:, 0] if squeeze else rejected)
