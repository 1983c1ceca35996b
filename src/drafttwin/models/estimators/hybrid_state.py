"""What a residual hybrid's model file holds beyond its networks, read back and checked before
it is trusted (a ``ValueError`` names the field; the model file reader turns it into a
:class:`~drafttwin.errors.ModelFileError`)."""

from __future__ import annotations

from typing import Any

import numpy as np


def relative_state(state: dict[str, Any], n_out: int, n_in: int) -> tuple[np.ndarray, np.ndarray]:
    """The relative structure's references from a model file (checked: finite, positive,
    one per channel / input)."""
    rel = state["relative"]
    floor = np.asarray(rel["level_floor"], dtype=np.float64)
    ref = np.asarray(rel["input_ref"], dtype=np.float64)
    for what, arr, n in (("level_floor", floor, n_out), ("input_ref", ref, n_in)):
        if arr.shape != (n,) or not (np.isfinite(arr).all() and (arr > 0).all()):
            raise ValueError(f"relative.{what} must hold {n} finite positive numbers")
    return floor, ref


def corrected_channels(state: dict[str, Any], correct: bool, n_out: int) -> np.ndarray:
    """Per output channel, whether the model file's residual model corrects it (checked:
    one bool per channel; files before the per-channel choice: all as ``correct``)."""
    flags = state.get("corrected")
    if flags is None:
        return np.full(n_out, correct)
    if (not isinstance(flags, list) or len(flags) != n_out
            or not all(isinstance(f, bool) for f in flags)):  # fmt: skip
        raise ValueError(f"corrected must list one true/false per output channel ({n_out})")
    return np.array(flags, dtype=bool)


def offset_channels(state: dict[str, Any], corrected: np.ndarray) -> np.ndarray:
    """Per output channel, whether the model file's hybrid corrects it by the measured
    offset held (checked: one bool per channel, each one a corrected channel; files before
    that candidate: none)."""
    flags = state.get("offset")
    if flags is None:
        return np.zeros(corrected.shape, dtype=bool)
    n_out = corrected.size
    if (not isinstance(flags, list) or len(flags) != n_out
            or not all(isinstance(f, bool) for f in flags)):  # fmt: skip
        raise ValueError(f"offset must list one true/false per output channel ({n_out})")
    out = np.array(flags, dtype=bool)
    if (out & ~corrected).any():
        raise ValueError("offset names a channel the model does not correct (corrected)")
    return out
