"""Bounds on every numeric option of every command, checked while the command line is parsed.

Each numeric option names its range here once; :func:`bounded` is its typer callback. A value
out of range (zero where it must be positive, NaN, infinity, 1e300) is refused before any
work starts, with one line that names the option and the range::

    error: --rate 0: must be > 0 and <= 1e+06 Hz

``tests/reliability/test_cli_inputs.py`` checks that every numeric option of every command
has a callback from here.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

from drafttwin.errors import ConfigError

N = TypeVar("N", int, float)


@dataclass(frozen=True)
class Bound:
    """An option's range: ``low < x`` (or ``low <= x`` when ``low_inclusive``), ``x <= high``."""

    low: float
    high: float
    unit: str = ""
    low_inclusive: bool = False

    def accepts(self, x: float) -> bool:
        if not math.isfinite(x) or x > self.high:
            return False
        return x >= self.low if self.low_inclusive else x > self.low

    def describe(self) -> str:
        low = f">= {_num(self.low)}" if self.low_inclusive else f"> {_num(self.low)}"
        unit = f" {self.unit}" if self.unit else ""
        return f"must be {low} and <= {_num(self.high)}{unit}"


def _num(x: float) -> str:
    """3600 as 3600, 4294967295 in full, 1e6 as 1e+06."""
    text = str(int(x)) if float(x).is_integer() else ""
    return text if text and len(text) <= 10 and not text.endswith("000000") else f"{x:g}"


_SEED_MAX = 2**32 - 1  # NumPy and torch seeds are 32-bit

#: every numeric option of the CLI and its range, as an interval and a unit: "(0, 1e6] Hz" is
#: 0 < x <= 1e6, "[0, 3600] s" is 0 <= x <= 3600; the same name means the same quantity in
#: every command
_RANGES: dict[str, str] = {
    "--motor-rpm": "(0, 1e5] rpm",
    "--duration": "(0, 1e6] s",
    "--rate": "(0, 1e6] Hz",
    "--dt": "[1e-07, 0.001] s",  # a drive-train file's [solver] dt_s
    "--settle": "[0, 3600] s",
    "--cutoff-hz": "(0, 1e6] Hz",
    "--rate-tolerance": "[0, 0.49] (fraction of a step)",
    "--threshold": "[0, 10] (fraction)",
    "--seed": f"[0, {_SEED_MAX}]",
    "--machine-seed": f"[0, {_SEED_MAX}]",
    "--seeds": "[1, 1000] seeds",
    "--init-samples": "[1, 1e7] samples",
    "--train-fraction": "[0.05, 1.0]",
    "--horizon": "[1, 1e5] samples",
    "--score-from": "[0, 1e9] samples",
    "--epochs": "[1, 1e6]",
    "--tune-budget": "(0, 1e5] CPU-minutes",
    "--tune-seed": f"[0, {_SEED_MAX}]",
    "--tune-trials": "[1, 100000] trials",
    "--block": "[0.001, 3600] s",
    "--workers": "[1, 1024]",
    "--max-samples": "[1, 1e9] samples",
    "--cases": "[1, 100000] cases",
    "--far-per-day": "[1e-6, 1e6] alarms per 24 h",  # 1e-6: one in 2700 years
    "--healthy-hours": "(0, 1000] h",
    "--commit-ms": "[1, 60_000] ms",
    "--retention-hours": "(0, 1e6] h",
    "--silent": "[0.05, 3600] s",
    "--learn": "[0, 86_400] s",
    "--speed": "(0, 10_000] x real time",
    "--batch": "[1, 200] samples",
    "--gap": "[0, 86_400] s",
    "--lead": "[0, 3600] s",
    "--plant-machines": "[0, 50] machines",
    "--from": "[0, 1e11] s",
    "--to": "[0, 1e11] s",
    "--machines": "[1, 10_000] machines",
    "--shards": "[1, 1000] twins",
    "--history": "[0, 86_400] s",
    "--ramp": "(0, 1e4] Hz/s",
    "--reference": "(0, 3600] s",
    "--doublings": "[1, 16] slivers",
    "--feed-ktex": "[0.05, 100] ktex",
    "--feed-cv": "[0, 0.49] (fraction)",
    "--feed-correlation": "[0.01, 1e4] m",
    "--fineness-dtex": "(0, 100] dtex",
    "--fineness-cv": "[0, 1.5] (fraction)",
    "--step-mm": "[0.05, 50] mm",
    "--fibre-scale": "[1, 1e6] fibres per drawn fibre",
    "--harmonics": "[1, 20] harmonics",
    "--sensor-mm": "[0, 1000] mm",
    "--tested-m": "(0, 1e7] m",
    "--nominal-count": "(0, 1000] ktex",
    "--post": "(0, 3600] s",
    "--qos": "[0, 1] (MQTT QoS)",
    "--max-lag": "(0, 3600] s",
    "--action-point": "[0, 10_000] mm of fed sliver",
    "--intensity": "[0, 2] (fraction of the excess corrected)",
    "--reference-ktex": "(0, 1600] ktex",
    "--max-length": "(0, 1e6] m",
    "--search": "[5, 2000] mm",
    "--level-window": "[20, 10_000] m",
    "--level-search": "[5, 2000] mm",
    "--fault-cases": "[0, 1000] machines",
}


def _interval(text: str) -> Bound:
    """``"(0, 1e6] Hz"`` -> ``Bound(0, 1e6, "Hz")``; a ``[`` makes the low end inclusive."""
    match = re.fullmatch(r"([(\[])([^,]+), ([^\]]+)\] ?(.*)", text)
    if match is None:
        raise ValueError(f"not an interval and unit: {text!r}")
    opening, low, high, unit = match.groups()
    return Bound(float(low), float(high), unit, low_inclusive=opening == "[")


BOUNDS: dict[str, Bound] = {option: _interval(text) for option, text in _RANGES.items()}


def check(option: str, value: N) -> N:
    """``value`` if it lies in ``option``'s range, else a ConfigError naming both."""
    bound = BOUNDS[option]
    try:
        x = float(value)
    except OverflowError:  # an int beyond any float
        x = math.inf
    if not bound.accepts(x):
        shown = str(value) if isinstance(value, int) and abs(value) < 10**12 else f"{x:g}"
        raise ConfigError(bound.describe(), where=f"{option} {shown}")
    return value


def range_of(option: str) -> str | None:
    """The range text of ``option`` (for a value that is not even a number), if it has one."""
    bound = BOUNDS.get(option)
    return None if bound is None else bound.describe()


def bounded(option: str) -> Callable[[N | None], N | None]:
    """The typer callback of a numeric option (``None``, the option left out, passes)."""
    if option not in BOUNDS:
        raise KeyError(f"no bound for {option}: add it to BOUNDS")

    def callback(value: N | None) -> N | None:
        return None if value is None else check(option, value)

    callback.__name__ = f"bounded_{option.strip('-').replace('-', '_')}"
    return callback
