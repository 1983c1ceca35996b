"""What a physics source gives, checked: a callable of the time (and the inputs) as a record
function, and its values as a ``(rows, channels)`` float64 array with every value finite
(:class:`~drafttwin.models.mechanistic.MechanisticModel`)."""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from drafttwin.errors import DataError

RecordFunction = Callable[[np.ndarray, dict[str, np.ndarray], tuple[str, ...], dict[str, str]], Any]
"""What a source computes for one record: ``f(time_s, inputs, channels, units)``."""


def is_path_list(source: object) -> bool:
    return (
        isinstance(source, list | tuple)
        and bool(source)
        and all(isinstance(p, str | Path) for p in source)
    )


def adapt_callable(fn: Callable[..., Any]) -> RecordFunction:
    """``f(time_s)`` or ``f(time_s, inputs)`` as a record function."""
    try:
        params = [
            p
            for p in inspect.signature(fn).parameters.values()
            if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD, p.VAR_POSITIONAL)
        ]
    except (TypeError, ValueError):  # builtins without a signature: one argument
        params = []
    takes_inputs = len(params) >= 2 or any(p.kind == p.VAR_POSITIONAL for p in params)
    if takes_inputs:
        return lambda t, inputs, channels, units: fn(t, inputs)
    return lambda t, inputs, channels, units: fn(t)


def check_values(
    values: object,
    n: int,
    names: tuple[str, ...],
    provided: tuple[str, ...] | None,
    source: str,
) -> np.ndarray:
    """Validate a source's result: pick ``names`` from a frame/dict or from ``provided``
    columns, check the shape and that every value is finite."""
    if isinstance(values, pd.DataFrame | Mapping):
        missing = [c for c in names if c not in values]
        if missing:
            raise DataError(f"the source gives no channel(s) {missing}", source=source,
                            fix=f"return a column for each of {', '.join(names)}")  # fmt: skip
        arr = np.column_stack([np.asarray(values[c], dtype=np.float64) for c in names])
    else:
        arr = np.asarray(values, dtype=np.float64)
        if arr.ndim == 1:
            arr = arr[:, None]
        if provided is not None and arr.ndim == 2 and arr.shape[1] == len(provided):
            if any(c not in provided for c in names):
                raise DataError(
                    f"the source gives channels {list(provided)}, not {list(names)}",
                    source=source,
                    fix="build the MechanisticModel with channels= the data's output channels",
                )
            arr = arr[:, [provided.index(c) for c in names]]
    if arr.ndim != 2 or arr.shape != (n, len(names)):
        raise DataError(
            f"expected values of shape ({n}, {len(names)}) (one column per channel: "
            f"{', '.join(names)}), got shape {arr.shape}",
            source=source,
            fix=f"return one column per channel in the order {', '.join(names)}",
        )
    bad = ~np.isfinite(arr)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise DataError("mechanistic values must be finite", source=source,
                        where=f"row {row}, channel {names[col]}",
                        fix="fill or drop the missing simulator output")  # fmt: skip
    return arr
