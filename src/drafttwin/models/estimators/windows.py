"""Causal windows: the only way model inputs are cut from a series.

Every model builds its inputs through :func:`gather_windows`, which for a target row ``T`` and
horizon ``h`` takes rows ``T-h-W+1 .. T-h`` of a feature array and nothing later. Measured
speeds and residuals therefore reach a model only up to ``T-h`` (``t-1`` for ``h = 1``). The
mechanistic prediction and the data-driven prediction *for* ``T`` enter separately as "extra"
inputs taken at row ``T`` (they are known at that time).

Missing samples are filled with :func:`causal_ffill` (last observation carried forward), which
uses only earlier rows, so filling cannot leak the future either. A series may hold several
records (separate experiments): no window, fill or change crosses a record boundary.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view


def causal_ffill(x: np.ndarray, starts: Sequence[int] = (0,)) -> np.ndarray:
    """Forward-fill ``NaN`` along axis 0 with the last earlier finite value of each column,
    never across a record boundary (``starts``: first row of each record).

    Rows before a column's first finite value in a record stay ``NaN``. Uses rows ``<= i`` of
    the same record only for row ``i``. Units are those of ``x``.
    """
    x = np.array(x, dtype=np.float64, copy=True)
    if x.ndim == 1:
        return causal_ffill(x[:, None], starts)[:, 0]
    n = x.shape[0]
    if n == 0:
        return x
    rows = np.where(np.isnan(x), 0, np.arange(n)[:, None])
    barriers = np.asarray([s for s in starts if 0 < s < n], dtype=np.int64)
    rows[barriers] = barriers[:, None]  # a record start is its own last value (NaN or not)
    np.maximum.accumulate(rows, axis=0, out=rows)
    return x[rows, np.arange(x.shape[1])[None, :]]


def record_ids(n: int, starts: Sequence[int] = (0,)) -> np.ndarray:
    """Record index of each of ``n`` rows, from the records' first rows ``starts``."""
    marks = np.zeros(n, dtype=np.int64)
    inner = [s for s in starts if 0 < s < n]
    marks[inner] = 1
    return np.cumsum(marks)


def increments(x: np.ndarray, starts: Sequence[int] = (0,)) -> np.ndarray:
    """Per-sample change ``x(T) - x(T-1)`` (0 at the first row of each record), same units and
    shape as ``x``."""
    x = np.asarray(x, dtype=np.float64)
    out = np.zeros_like(x)
    out[1:] = x[1:] - x[:-1]
    out[[s for s in starts if 0 < s < len(x)]] = 0.0
    return out


def first_target(window: int, horizon: int) -> int:
    """The first row that has a full input window: ``window + horizon - 1``."""
    return window + horizon - 1


def target_rows(n: int, window: int, horizon: int, starts: Sequence[int] = (0,)) -> np.ndarray:
    """All rows ``T`` of an ``n``-row series that have a full window of ``window`` rows ending at
    ``T - horizon`` inside ``T``'s own record (``starts``: first row of each record)."""
    first = first_target(window, horizon)
    rows = np.arange(first, max(n, first))
    if len(starts) <= 1 or rows.size == 0:
        return rows
    rec = record_ids(n, starts)
    in_record: np.ndarray = rows[rec[rows - first] == rec[rows]]
    return in_record


def gather_windows(
    features: np.ndarray, targets: np.ndarray, window: int, horizon: int
) -> np.ndarray:
    """Input windows for the target rows, shape ``(len(targets), window, n_features)``, float32.

    The window for target ``T`` holds rows ``T-horizon-window+1 .. T-horizon`` of ``features``
    (oldest first). Raises ``ValueError`` if a window would start before row 0.
    """
    features = np.asarray(features, dtype=np.float64)
    if features.ndim == 1:
        features = features[:, None]
    targets = np.asarray(targets, dtype=np.int64)
    n_feat = features.shape[1]
    if targets.size == 0:
        return np.zeros((0, window, n_feat), dtype=np.float32)
    starts = targets - horizon - window + 1
    if starts.min() < 0 or targets.max() >= features.shape[0]:
        raise ValueError("a window reaches outside the series")
    view = sliding_window_view(features, window, axis=0)  # (n-window+1, n_feat, window)
    return np.ascontiguousarray(view[starts].transpose(0, 2, 1), dtype=np.float32)


def finite_rows(*arrays: np.ndarray) -> np.ndarray:
    """Boolean mask over the first axis: ``True`` where every value in every array is finite."""
    mask: np.ndarray | None = None
    for arr in arrays:
        ok = np.isfinite(arr).reshape(arr.shape[0], int(np.prod(arr.shape[1:]))).all(axis=1)
        mask = ok if mask is None else mask & ok
    if mask is None:
        raise ValueError("finite_rows needs at least one array")
    return mask


def blocked_folds(start: int, stop: int, n_folds: int) -> list[tuple[int, int]]:
    """Split rows ``start .. stop-1`` into ``n_folds`` contiguous blocks ``[a, b)``, in order."""
    edges = np.linspace(start, stop, n_folds + 1).round().astype(int)
    return [(int(edges[k]), int(edges[k + 1])) for k in range(n_folds)]


def record_folds(
    start: int, stop: int, starts: Sequence[int], n_folds: int
) -> list[tuple[int, int]]:
    """Folds of rows ``start .. stop-1`` that follow the records (first rows ``starts``): with
    two or more records in the span, whole records, one a fold, or with more records than
    ``n_folds`` contiguous runs of records cut nearest to equal sizes; with one record,
    :func:`blocked_folds`. A held-out record is then new to its judge as a test record is
    (its own offsets and load), where a block of a record shares them with its neighbours."""
    inner = sorted({int(s) for s in starts if start < s < stop})
    if not inner:
        return blocked_folds(start, stop, n_folds)
    if len(inner) + 1 > n_folds:
        marks = np.asarray(inner)
        wanted = np.linspace(start, stop, n_folds + 1)[1:-1]
        inner = sorted({int(marks[np.abs(marks - w).argmin()]) for w in wanted})
    edges = [start, *inner, stop]
    return [(edges[k], edges[k + 1]) for k in range(len(edges) - 1)]


def footprint_outside(
    targets: np.ndarray, window: int, horizon: int, block: tuple[int, int]
) -> np.ndarray:
    """Mask of targets whose rows ``T-horizon-window+1 .. T`` (inputs and target) all lie outside
    the held-out ``block = [a, b)``."""
    a, b = block
    first_input = targets - horizon - window + 1
    return (targets < a) | (first_input >= b)
