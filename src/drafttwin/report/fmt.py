"""Number and text formatting shared by the report's modules."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, TypeGuard

DASH = "—"


def is_num(x: Any) -> TypeGuard[float]:
    """True for a finite real number (not bool, not None, not NaN)."""
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def num(x: Any, nd: int = 3) -> str:
    """A number with ``nd`` decimals; a dash for None / NaN."""
    return f"{x:.{nd}f}" if is_num(x) else DASH


def sig(x: Any, digits: int = 3) -> str:
    """A number with ``digits`` significant digits (losses, learning rates)."""
    return f"{x:.{digits}g}" if is_num(x) else DASH


def sig_fixed(x: Any, digits: int = 3) -> str:
    """A number to ``digits`` significant digits, trailing zeros kept (``2.00``, ``0.720``,
    ``118``); a dash for None / NaN."""
    if not is_num(x):
        return DASH
    if x == 0:
        return "0"
    return f"{x:.{max(0, digits - 1 - math.floor(math.log10(abs(x))))}f}"


def seconds(s: Any) -> str:
    """A duration: ``12.3 s``, ``4 min 05 s``, ``1 h 02 min``."""
    if not is_num(s):
        return DASH
    if s < 60:
        return f"{s:.1f} s"
    if s < 3600:
        return f"{int(s // 60)} min {int(round(s % 60)):02d} s"
    return f"{int(s // 3600)} h {int(round(s % 3600 / 60)):02d} min"


def count_text(names: Sequence[str], total: int = 4) -> str:
    """``"all four rollers"``, ``"no roller"`` or ``"2 of 4 (front, third)"``."""
    if len(names) == total:
        return "all four rollers" if total == 4 else f"all {total}"
    if not names:
        return "no roller"
    return f"{len(names)} of {total} ({', '.join(names)})"


def span(values: Sequence[float], nd: int = 3, unit: str = "") -> str:
    """``"0.011–0.049 %"`` or ``"−1.99 to −0.19"``: the range of the finite values."""
    vals = [v for v in values if is_num(v)]
    if not vals:
        return DASH
    lo, hi = min(vals), max(vals)
    a, b = num(lo, nd).replace("-", "−"), num(hi, nd).replace("-", "−")
    text = a if a == b else (f"{a} to {b}" if lo < 0 else f"{a}–{b}")
    return f"{text}{unit}"


def with_unit(label: str, unit: str) -> str:
    """``"RMSE (rpm)"``; the bare label when the unit is unknown (``""``)."""
    return f"{label} ({unit})" if unit else label
