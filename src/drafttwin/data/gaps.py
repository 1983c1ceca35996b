"""Missing samples: the runs of ``NaN`` and their linear interpolation (paper eq. 12), record by
record (the policies are in :mod:`drafttwin.data.preprocessing`)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def nan_runs(missing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start indices and lengths of the runs of ``True`` in a 1-D boolean array."""
    edges = np.diff(np.concatenate(([0], missing.astype(np.int8), [0])))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1)
    return starts, ends - starts


def record_spans(n: int, record_starts: Sequence[int] | None) -> list[tuple[int, int]]:
    """``[(start, stop), ...]`` of the records of ``n`` rows (one record by default)."""
    starts = [int(s) for s in (record_starts or (0,)) if 0 < int(s) < n]
    return [(a, b) for a, b in zip([0, *starts], [*starts, n], strict=True) if b > a]


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
    values: np.ndarray, max_gap: int | None = None, record_starts: Sequence[int] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Fill missing samples (``NaN``) by linear interpolation (paper eq. 12), record by record.

    Args:
        values: samples, shape ``(n,)`` or ``(n, k)``, in any unit.
        max_gap: the longest run of missing samples to fill (samples); longer runs stay
            ``NaN``. ``None`` fills every gap. Leading and trailing gaps (of each record) take
            the nearest valid value. A column without any valid sample stays ``NaN``.
        record_starts: first row of each record; a gap is never bridged across records.

    Returns:
        ``(filled, filled_mask)``: the new array (same shape, float64) and a boolean mask of
        the samples that were filled.
    """
    if max_gap is not None and max_gap < 0:
        raise ValueError(f"max_gap must be >= 0 or None, got {max_gap}")
    x = np.asarray(values, dtype=np.float64)
    x2 = x.reshape(x.shape[0], -1)
    out = np.empty_like(x2)
    for a, b in record_spans(x2.shape[0], record_starts):
        for j in range(x2.shape[1]):
            out[a:b, j] = _fill_column(x2[a:b, j], max_gap)
    filled = out.reshape(x.shape)
    return filled, np.isnan(x) & ~np.isnan(filled)
