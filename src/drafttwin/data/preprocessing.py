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
  the tolerance *in the same direction*, i.e. it is a one-sample spike. The tolerance is
  ``threshold`` times each neighbour's magnitude (the paper's relative rule) for speeds in rpm
  and for channels whose values stay clear of zero; for a channel that crosses or sits near
  zero (a position, a voltage) 10 % of the value means nothing, so the tolerance is
  ``threshold`` times the channel's scale, the spread between its 1st and 99th percentiles. "Both" rather than the paper's "either": with "either", the two samples
  next to a spike, and both sides of every genuine step change, would be flagged too. In
  :func:`preprocess` a sample's neighbours are the nearest *measured* samples
  (:func:`find_measured_outliers`), across the gaps interpolation bridges: the samples that
  anchor a gap's interpolation are tested against each other. The first and last samples
  (one neighbour) and samples next to a gap left open are never flagged. An outlier is
  replaced by the mean of its neighbours (paper); a run of adjacent outliers (alternating
  spikes) is interpolated between its nearest good neighbours. Bursts of two or more equal
  wrong samples are not one-sample spikes and are not detected.
* **Order**: the paper interpolates first, then smooths. Where no spike touches a gap that is
  what :func:`preprocess` gives; a spike next to a gap is found against the measured samples
  and the gap and the spike are filled together from the good ones (filled first, a gap took
  the spike as an anchor: 509 rpm on a 434-rpm roller, which survived the smoothing).
* **Records** (separate experiments in one series) are preprocessed apart: no interpolation
  or outlier test uses a sample of another record; a record's first and last samples are edges.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from drafttwin.data.extremes import range_stretchers
from drafttwin.data.gaps import interpolate_missing, nan_runs, record_spans
from drafttwin.data.series import MeasurementSeries
from drafttwin.data.units import is_rpm
from drafttwin.errors import DataError

RELATIVE = "relative"
"""Outlier rule: tolerance = threshold x |neighbour| (the paper's rule)."""
SCALE = "scale"
"""Outlier rule: tolerance = threshold x the channel's 1st-99th percentile spread."""
SCALE_PERCENTILES: tuple[float, float] = (1.0, 99.0)


def _tolerance(neighbour: np.ndarray, threshold: float, scale: np.ndarray | None) -> np.ndarray:
    """Per-sample tolerance: relative to the neighbour, or to the column's scale where given
    (``NaN`` in ``scale`` = relative rule for that column)."""
    relative: np.ndarray = threshold * np.abs(neighbour)
    if scale is None:
        return relative
    tolerance: np.ndarray = np.where(np.isnan(scale), relative, threshold * np.nan_to_num(scale))
    return tolerance


def find_outliers(
    values: np.ndarray,
    threshold: float = 0.10,
    scale: float | np.ndarray | None = None,
    record_starts: Sequence[int] | None = None,
) -> np.ndarray:
    """Mask of one-sample spikes: more than the tolerance away from both neighbours.

    The deviation from a neighbour ``a`` counts when ``|x - a| > threshold * |a|`` (relative
    rule) or, for a column with a ``scale``, ``|x - a| > threshold * scale`` (scale rule), and
    both deviations have the same sign (the sample is above both neighbours or below both).
    ``scale``: ``None`` = relative rule everywhere; else one value per column, ``NaN`` for a
    column on the relative rule. The first and last sample of every record are never flagged.
    """
    x = np.asarray(values, dtype=np.float64)
    mask = np.zeros(x.shape, dtype=bool)
    if x.shape[0] < 3:
        return mask
    sc = None if scale is None else np.asarray(scale, dtype=np.float64)
    if sc is not None and np.isnan(sc).all():
        sc = None  # relative rule everywhere
    prev, cur, nxt = x[:-2], x[1:-1], x[2:]
    with np.errstate(over="ignore", invalid="ignore"):
        tol_p, tol_n = _tolerance(prev, threshold, sc), _tolerance(nxt, threshold, sc)
        up = (cur - prev > tol_p) & (cur - nxt > tol_n)
        down = (prev - cur > tol_p) & (nxt - cur > tol_n)
    mask[1:-1] = up | down
    for a, _ in record_spans(x.shape[0], record_starts)[1:]:
        mask[a - 1 : a + 1] = False  # the neighbour across a record boundary is not one
    return mask


def find_measured_outliers(
    values: np.ndarray,
    threshold: float = 0.10,
    scale: float | np.ndarray | None = None,
    record_starts: Sequence[int] | None = None,
    max_gap: int | None = None,
) -> np.ndarray:
    """:func:`find_outliers` on the measured samples (``NaN`` = missing): a sample's
    neighbours are the nearest measured samples of its record on either side, across the gaps
    that interpolation bridges (every gap with ``max_gap=None``, else those of at most
    ``max_gap`` samples), the samples that anchor the gap's interpolation. A sample next to a
    gap left open is an edge, never flagged. Shape ``(n, k)`` (or ``(n,)``)."""
    x = np.asarray(values, dtype=np.float64)
    x2 = x.reshape(x.shape[0], -1)
    mask = np.zeros(x2.shape, dtype=bool)
    sc = None if scale is None else np.broadcast_to(np.asarray(scale, dtype=np.float64),
                                                    (x2.shape[1],))  # fmt: skip
    for a, b in record_spans(x2.shape[0], record_starts):
        for j in range(x2.shape[1]):
            idx = np.flatnonzero(~np.isnan(x2[a:b, j]))
            cut = (np.flatnonzero(np.diff(idx) - 1 > max_gap) + 1 if max_gap is not None
                   else np.zeros(0, dtype=int))  # fmt: skip
            for seg in np.split(idx, cut):
                col = None if sc is None else sc[j : j + 1]
                flags = find_outliers(x2[a + seg, j][:, None], threshold, col)[:, 0]
                mask[a + seg[flags], j] = True
    return mask.reshape(x.shape)


def smooth_outliers(
    values: np.ndarray,
    threshold: float = 0.10,
    scale: float | np.ndarray | None = None,
    record_starts: Sequence[int] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Replace one-sample spikes by the mean of their neighbours (paper's rule, "both" variant).

    Args:
        values: samples, shape ``(n,)`` or ``(n, k)``; ``NaN`` allowed (never flagged, and a
            sample next to a ``NaN`` is never flagged).
        threshold: deviation from each neighbour that makes a spike (0.10 = 10 %), relative to
            the neighbour, or to ``scale`` (see :func:`find_outliers`).
        scale: per-column scale for the scale rule (``None`` / ``NaN``: relative rule).
        record_starts: first row of each record; record edges are never flagged, so a
            replacement only uses samples of its own record.

    Returns:
        ``(smoothed, outlier_mask)``.
    """
    if not threshold >= 0:
        raise ValueError(f"threshold must be >= 0, got {threshold}")
    x = np.asarray(values, dtype=np.float64)
    x2 = x.reshape(x.shape[0], -1)
    mask2 = find_outliers(x2, threshold, scale, record_starts)
    out = x2.copy()
    for j in np.flatnonzero(mask2.any(axis=0)):
        # a flagged run is bracketed by valid, unflagged samples of the same record
        bad = mask2[:, j]
        good = np.flatnonzero(~bad & ~np.isnan(x2[:, j]))
        out[bad, j] = np.interp(np.flatnonzero(bad), good, x2[good, j])
    return out.reshape(x.shape), mask2.reshape(x.shape)


def outlier_scale(values: np.ndarray, unit: str = "") -> float | None:
    """The scale for the scale rule, or ``None`` where the paper's relative rule applies.

    Speeds in rpm keep the relative rule. Other channels keep it when their robust range
    (1st to 99th percentile) lies on one side of zero at least its own width away from it,
    i.e. where 10 % of the value is everywhere at least 10 % of the spread; otherwise (the
    channel crosses or sits near zero) the scale is that spread.
    """
    if is_rpm(unit):
        return None
    x = np.asarray(values, dtype=np.float64)
    x = x[np.isfinite(x)]
    if x.shape[0] == 0:
        return None
    lo, hi = (float(q) for q in np.percentile(x, SCALE_PERCENTILES))
    spread = hi - lo
    if (lo > 0 or hi < 0) and min(abs(lo), abs(hi)) >= spread:
        return None
    return spread


@dataclass
class PreprocessReport:
    """What preprocessing changed, per output channel (counts in samples)."""

    channels: tuple[str, ...]
    missing: np.ndarray  # (n, k) bool: NaN in the input
    filled: np.ndarray  # (n, k) bool: filled by interpolation / edge hold
    outliers: np.ndarray  # (n, k) bool: replaced by the neighbour mean
    max_gap: int | None = None
    threshold: float | None = 0.10  # None: smoothing skipped
    extra: dict[str, int] = field(default_factory=dict)  # motor / input samples filled
    scales: dict[str, float | None] = field(default_factory=dict)  # None: relative rule
    record_starts: tuple[int, ...] = (0,)
    stretched: dict[str, dict[str, float]] = field(default_factory=dict)  # see data.extremes

    @property
    def rollers(self) -> tuple[str, ...]:
        """The channel names (the four rollers for FA320A data)."""
        return self.channels

    @property
    def rules(self) -> dict[str, str]:
        """Outlier rule per channel: ``relative`` (the paper's) or ``scale``."""
        return {c: RELATIVE if self.scales.get(c) is None else SCALE for c in self.channels}

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
        """Per channel: number of runs of missing samples and the longest run (samples);
        a run never continues into the next record."""
        out = {}
        bounds = record_spans(self.missing.shape[0], self.record_starts)
        for j, r in enumerate(self.channels):
            lengths = np.concatenate(
                [nan_runs(self.missing[a:b, j])[1] for a, b in bounds] or [np.zeros(0, int)]
            )
            out[r] = {"count": int(lengths.shape[0]), "longest": int(lengths.max(initial=0))}
        return out

    def _count(self, mask: np.ndarray) -> dict[str, int]:
        return {r: int(c) for r, c in zip(self.channels, mask.sum(axis=0), strict=True)}

    def to_dict(self) -> dict[str, Any]:
        """Counts only (no masks), JSON-ready."""
        out: dict[str, Any] = {
            "max_gap": self.max_gap,
            "outlier_threshold": self.threshold,
            "missing": self.n_missing,
            "filled": self.n_filled,
            "left_missing": self.n_left_missing,
            "outliers": self.n_outliers,
            "gaps": self.gaps(),
            "other_channels_filled": dict(self.extra),
        }
        if self.stretched:  # only when found: the metadata of clean data stay as they were
            out["range_stretched"] = {c: dict(v) for c, v in self.stretched.items()}
        if self.threshold is not None:
            out["outlier_rule"] = self.rules
            scaled = {c: s for c, s in self.scales.items() if s is not None}
            if scaled:
                out["outlier_scale"] = scaled
        return out


def _hold(x: np.ndarray) -> np.ndarray:
    """Missing samples take the last valid value (leading ones the first valid value)."""
    valid = ~np.isnan(x)
    if valid.all() or not valid.any():
        return x
    idx = np.maximum.accumulate(np.where(valid, np.arange(x.shape[0]), -1))
    idx[idx < 0] = np.flatnonzero(valid)[0]
    return x[idx]


def _fill_optional(
    series: MeasurementSeries, max_gap: int | None
) -> tuple[dict[str, Any], dict[str, int]]:
    """Motor speed: interpolated like the outputs; inputs: last value held (then first), within
    each record."""
    counts: dict[str, int] = {}
    changes: dict[str, Any] = {}
    starts = series.record_starts
    if series.motor_rpm is not None:
        motor, filled = interpolate_missing(series.motor_rpm, max_gap, starts)
        changes["motor_rpm"], counts["motor"] = motor, int(filled.sum())
    inputs = {}
    for name, values in series.inputs.items():
        x = np.asarray(values, dtype=np.float64)
        n_missing = int(np.isnan(x).sum())
        if not n_missing or not (~np.isnan(x)).any():
            inputs[name] = x
            continue
        inputs[name] = np.concatenate([_hold(x[a:b]) for a, b in record_spans(len(x), starts)])
        counts[name] = n_missing - int(np.isnan(inputs[name]).sum())
    if inputs:
        changes["inputs"] = inputs
    return changes, counts


def outlier_scales(series: MeasurementSeries) -> dict[str, float | None]:
    """Per output channel: the scale rule's scale, or ``None`` for the relative rule (see
    :func:`outlier_scale`), from the series' values and units."""
    return {
        c: outlier_scale(series.values[:, j], series.unit(c)) for j, c in enumerate(series.channels)
    }


def preprocess(
    series: MeasurementSeries,
    *,
    max_gap: int | None = None,
    outlier_threshold: float | None = 0.10,
) -> tuple[MeasurementSeries, PreprocessReport]:
    """Interpolate missing samples, then smooth one-sample outliers (the paper's order), each
    record on its own.

    Args:
        series: measured outputs, ``NaN`` = missing.
        max_gap: longest run of missing samples to fill; ``None`` fills all (see module doc).
        outlier_threshold: spike threshold (0.10 = the paper's 10 %), relative to each
            neighbour, or to the channel's 1st-99th percentile spread for channels that cross
            or sit near zero (see :func:`outlier_scale`); ``None`` skips outlier smoothing.

    Returns:
        ``(clean series, report)``. The clean series' ``metadata["preprocess"]`` holds the
        report's counts and the outlier rule of each channel. Motor speed is interpolated like
        the outputs; inputs hold their last value.
    """
    starts = series.record_starts
    filled_values, filled = interpolate_missing(series.values, max_gap, starts)
    scales = outlier_scales(series) if outlier_threshold is not None else {}
    if outlier_threshold is None:
        clean, outliers = filled_values, np.zeros(filled.shape, dtype=bool)
    else:
        scale = np.array([np.nan if s is None else s for s in scales.values()])
        outliers = find_measured_outliers(series.values, outlier_threshold, scale, starts,
                                          max_gap)  # fmt: skip
        clean = filled_values
        if outliers.any():  # filled with the gaps from the measured samples that are neither,
            # so that a spike next to a gap does not anchor the gap's interpolation
            again, _ = interpolate_missing(np.where(outliers, np.nan, series.values), None,
                                           starts)  # fmt: skip
            clean = np.where(np.isnan(filled_values), np.nan, again)
    changes, extra = _fill_optional(series, max_gap)
    report = PreprocessReport(
        channels=series.channels,
        missing=np.isnan(series.values),
        filled=filled,
        outliers=outliers,
        max_gap=max_gap,
        threshold=None if outlier_threshold is None else float(outlier_threshold),
        extra=extra,
        scales=scales,
        record_starts=starts,
        stretched=range_stretchers(clean, series.time_s, series.channels),
    )
    metadata = {**series.metadata, "preprocess": report.to_dict()}
    return replace(series, values=clean, metadata=metadata, **changes), report


DEFAULT_TRAIN_FRACTION = 0.7
"""The share of a record that trains when nothing else is said: the paper's 70 % / 30 %
chronological split (the one place this default is written)."""


def chronological_split(
    series: MeasurementSeries, train_fraction: float = DEFAULT_TRAIN_FRACTION
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


def reject_spikes_causal(
    values: np.ndarray | MeasurementSeries,
    threshold: float = 0.10,
    *,
    record_starts: Sequence[int] | None = None,
    scale: float | np.ndarray | None = None,
    floor: float | np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Mark as missing (``NaN``) every sample that jumps more than the tolerance from the last
    accepted sample of its column; uses past samples only.

    The paper's outlier rule compares a sample with *both* neighbours, so it needs the next
    sample and cannot clean a model's inputs online. This causal variant can: a spike is
    dropped and the models hold the last value. A spike is one sample: when the next sample
    agrees with a rejected one (within the tolerance), the level has moved (a fast speed
    change) and the cleaning follows it from that sample on; only the first sample of such a
    step is held. The tolerance is ``threshold * |last accepted|`` (relative rule), or ``threshold *
    scale`` for a column with a ``scale`` (one per column, ``NaN`` = relative; take it from
    the training data with :func:`outlier_scales`, as the future is not known online). With a
    ``floor`` (one per column) the relative rule uses ``max(|last accepted|, floor)``: near
    standstill 10 % of the last value is nothing, and a start-up would be rejected sample
    after sample; take half the training part's typical magnitude. Each record starts afresh
    (``record_starts``, or the series' records): its first sample is never compared with
    another record's. Returns ``(cleaned values, rejected mask)``.
    """
    if isinstance(values, MeasurementSeries):
        record_starts = values.record_starts if record_starts is None else record_starts
        values = values.values
    x = np.array(values, dtype=np.float64, copy=True)
    squeeze = x.ndim == 1
    x2 = x[:, None] if squeeze else x
    rejected = np.zeros(x2.shape, dtype=bool)
    sc = np.broadcast_to(np.nan if scale is None else np.asarray(scale, float), x2.shape[1:])
    low = np.broadcast_to(0.0 if floor is None else np.asarray(floor, float), x2.shape[1:])
    is_start = np.zeros(x2.shape[0], dtype=np.bool_)
    for a, _ in record_spans(x2.shape[0], record_starts):
        is_start[a] = True
    x2 = np.ascontiguousarray(x2)
    _spike_kernel()(x2, is_start, float(threshold), np.ascontiguousarray(sc, dtype=np.float64),
                    np.ascontiguousarray(low, dtype=np.float64), rejected)  # fmt: skip
    return (x2[:, 0] if squeeze else x2), (rejected[:, 0] if squeeze else rejected)


def _reject_spikes_columns(
    x: np.ndarray, is_start: np.ndarray, threshold: float, scale: np.ndarray, low: np.ndarray,
    rejected: np.ndarray,
) -> None:  # fmt: skip
    """The causal spike rule in place, column by column (compiled by :func:`_spike_kernel`:
    sequential by nature, each decision depends on the last, and the evaluation protocol runs
    it on every test set)."""
    for j in range(x.shape[1]):
        last = np.nan  # last accepted value
        held = np.nan  # the sample rejected just before (if any)
        for i in range(x.shape[0]):
            if is_start[i]:
                last = np.nan
                held = np.nan
            v = x[i, j]
            if np.isnan(v):
                continue
            if not np.isfinite(last):  # a record's first sample: nothing to compare with
                last = v
                held = np.nan
                continue
            tol = threshold * (max(abs(last), low[j]) if np.isnan(scale[j]) else scale[j])
            moved = np.isfinite(held) and abs(v - held) <= tol
            if abs(v - last) > tol and not moved:
                rejected[i, j] = True
                held = v
                x[i, j] = np.nan
            else:
                last = v
                held = np.nan


_KERNEL: Any = None


def _spike_kernel() -> Any:
    """:func:`_reject_spikes_columns` compiled with numba on first use (cached on disk), so
    that importing the data layer does not load numba."""
    global _KERNEL
    if _KERNEL is None:
        from numba import njit

        _KERNEL = njit(cache=True)(_reject_spikes_columns)
    return _KERNEL
