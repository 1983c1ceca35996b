"""Strict JSON: never ``NaN`` or ``Infinity`` (which JSON does not have).

Every JSON document drafttwin prints or writes goes through :func:`dumps_strict`: a
non-finite number becomes ``null`` (read it as "not computable"), NumPy scalars and arrays
become numbers and lists, paths strings; anything else that is not JSON raises.
"""

from __future__ import annotations

import json
import math
from pathlib import PurePath
from typing import Any


def to_strict(obj: Any) -> Any:
    """``obj`` with every non-finite float replaced by ``None`` (recursively)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: to_strict(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_strict(v) for v in obj]
    if isinstance(obj, PurePath):
        return str(obj)
    if hasattr(obj, "tolist") and hasattr(obj, "dtype"):  # NumPy scalar or array
        return to_strict(obj.tolist())
    return obj


def dumps_strict(obj: Any, *, indent: int | None = 2, sort_keys: bool = False) -> str:
    """``json.dumps`` that never writes NaN or Infinity (they become ``null``)."""
    return json.dumps(to_strict(obj), indent=indent, sort_keys=sort_keys, allow_nan=False)
