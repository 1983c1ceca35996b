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

#: every numeric option of the CLI; the same name means the same quantity in every command
BOUNDS: dict[str, Bound] = {
    "--motor-rpm": Bound(0, 1e5, "rpm"),
    "--duration": Bound(0, 1e6, "s"),
    "--rate": Bound(0, 1e6, "Hz"),
    "--dt": Bound(0, 1.0, "s"),
    "--settle": Bound(0, 3600, "s", low_inclusive=True),
    "--cutoff-hz": Bound(0, 1e6, "Hz"),
    "--rate-tolerance": Bound(0, 0.49, "(fraction of a step)", low_inclusive=True),
    "--threshold": Bound(0, 10, "(fraction)", low_inclusive=True),
    "--seed": Bound(0, _SEED_MAX, low_inclusive=True),
    "--machine-seed": Bound(0, _SEED_MAX, low_inclusive=True),
    "--seeds": Bound(1, 1000, "seeds", low_inclusive=True),
    "--init-samples": Bound(1, 1e7, "samples", low_inclusive=True),
    "--train-fraction": Bound(0.05, 1.0, low_inclusive=True),
    "--horizon": Bound(1, 1e5, "samples", low_inclusive=True),
    "--score-from": Bound(0, 1e9, "samples", low_inclusive=True),
    "--epochs": Bound(1, 1e6, low_inclusive=True),
    "--block": Bound(0.001, 3600, "s", low_inclusive=True),
    "--workers": Bound(1, 1024, low_inclusive=True),
    "--max-samples": Bound(1, 1e9, "samples", low_inclusive=True),
    "--cases": Bound(1, 100000, "cases", low_inclusive=True),
    "--far-per-day": Bound(0, 1e6, "alarms per 24 h"),
    "--healthy-hours": Bound(0, 1000, "h"),
    "--commit-ms": Bound(1, 60_000, "ms", low_inclusive=True),
    "--retention-hours": Bound(0, 1e6, "h"),
    "--silent": Bound(0.05, 3600, "s", low_inclusive=True),
    "--from": Bound(0, 1e11, "s", low_inclusive=True),
    "--to": Bound(0, 1e11, "s", low_inclusive=True),
    "--machines": Bound(1, 10_000, "machines", low_inclusive=True),
    "--shards": Bound(1, 1000, "twins", low_inclusive=True),
    "--history": Bound(0, 86_400, "s", low_inclusive=True),
    "--ramp": Bound(0, 1e4, "Hz/s"),
    "--reference": Bound(0, 3600, "s"),
    "--doublings": Bound(1, 16, "slivers", low_inclusive=True),
    "--feed-ktex": Bound(0.05, 100, "ktex", low_inclusive=True),
    "--feed-cv": Bound(0, 0.49, "(fraction)", low_inclusive=True),
    "--feed-correlation": Bound(0.01, 1e4, "m", low_inclusive=True),
    "--fineness-dtex": Bound(0, 100, "dtex"),
    "--fineness-cv": Bound(0, 1.5, "(fraction)", low_inclusive=True),
    "--step-mm": Bound(0.05, 50, "mm", low_inclusive=True),
    "--fibre-scale": Bound(1, 1e6, "fibres per drawn fibre", low_inclusive=True),
    "--harmonics": Bound(1, 20, "harmonics", low_inclusive=True),
    "--sensor-mm": Bound(0, 1000, "mm", low_inclusive=True),
    "--post": Bound(0, 3600, "s"),
    "--qos": Bound(0, 1, "(MQTT QoS)", low_inclusive=True),
    "--max-lag": Bound(0, 3600, "s"),
}


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
