"""The delivered count against the machine's nominal: a quality monitor's count limit.

A drawframe's quality monitor shows the delivered count and stops the machine when it
deviates past a limit (research/sliver.md 5, [38]): a card sliver running out or breaking
with no leveller to make up for it (the count falls by one sliver in the doublings, a sixth
of six), a leveller that no longer levels, a wrong change gear. :class:`CountWatch` keeps the
mean count over the last :data:`LENGTH_M` metres of delivered sliver and says when it leaves
+-:data:`LIMIT_PCT` of the nominal count and when it is back within the limit (less a tenth
of it, so that a mean lying on the limit does not chatter). The nominal is the machine's own
(:func:`nominal_count_ktex`: its feed's count times the doublings over the total draft, as a
plant record's sidecar and a served machine's description say). The offline ``diagnose`` and
the live twin watch it alike (inside :class:`drafttwin.sliver.watch.SliverWatch`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

LIMIT_PCT = 5.0
"""The count limit, % either side of the nominal. A 5-m mean passes a wave of length
``lambda`` by ``|sinc(5 m / lambda)|``: the leveller benchmark's feed waves (1-5 m, up to 5 %)
move it by at most 1.1 % unlevelled, a wave of 10 m by 64 % of its amplitude; a missing
sliver of six takes it 16.7 % down."""
LENGTH_M = 5.0
"""Delivered sliver the count's mean is taken over, m."""
BACK = 0.9
"""The count is back when it lies within this share of the limit."""


def nominal_count_ktex(section: Mapping[str, Any]) -> float | None:
    """The nominal delivered count of a sliver description (``feed_ktex`` x ``doublings`` /
    ``drafts.total``), or None where it names none or names it out of range."""
    try:
        drafts = section["drafts"]
        value = (float(section["feed_ktex"]) * float(section["doublings"])
                 / float(drafts["total"]))  # fmt: skip
    except (KeyError, TypeError, ValueError, ZeroDivisionError):
        return None
    return value if math.isfinite(value) and 0 < value <= 1000 else None


@dataclass(frozen=True)
class CountExcursion:
    """The count leaving its limit (``out``) or coming back within it."""

    time_s: float
    delivered_m: float
    count_ktex: float  # mean over the last LENGTH_M metres
    nominal_ktex: float
    limit_pct: float
    out: bool

    @property
    def deviation_pct(self) -> float:
        return 100.0 * (self.count_ktex / self.nominal_ktex - 1.0)

    def text(self) -> str:
        if self.out:
            return (f"sliver count {self.count_ktex:.3f} ktex over the last {LENGTH_M:g} m, "
                    f"{self.deviation_pct:+.1f} % off the nominal {self.nominal_ktex:.3f} ktex "
                    f"(limit +-{self.limit_pct:g} %) after {self.delivered_m:.0f} m: a card "
                    "sliver run out or broken, a leveller not levelling or a wrong change gear")  # fmt: skip
        return (f"sliver count back within +-{self.limit_pct:g} % of the nominal: "
                f"{self.count_ktex:.3f} ktex ({self.deviation_pct:+.1f} %) after "
                f"{self.delivered_m:.0f} m")  # fmt: skip

    def to_dict(self) -> dict[str, Any]:
        return {**vars(self), "deviation_pct": self.deviation_pct, "text": self.text()}


@dataclass
class CountWatch:
    """The mean count over the last ``length_m`` metres against ``nominal_ktex`` (see the
    module's docstring)."""

    nominal_ktex: float
    limit_pct: float = LIMIT_PCT
    length_m: float = LENGTH_M
    outside: bool = False
    excursions: list[CountExcursion] = field(default_factory=list)
    _s: np.ndarray = field(default_factory=lambda: np.empty(0), repr=False)
    _x: np.ndarray = field(default_factory=lambda: np.empty(0), repr=False)

    def push(self, delivered_m: np.ndarray, ktex: np.ndarray,
             time_s: np.ndarray) -> list[CountExcursion]:  # fmt: skip
        """Readings in delivered order; the excursions they make (also kept in
        :attr:`excursions`)."""
        s = np.concatenate([self._s, np.asarray(delivered_m, dtype=np.float64)])
        x = np.concatenate([self._x, np.asarray(ktex, dtype=np.float64)])
        t = np.asarray(time_s, dtype=np.float64)
        new = s.size - t.size
        sums = np.concatenate([[0.0], np.cumsum(x)])
        ends = np.arange(new, s.size)
        starts = np.searchsorted(s, s[ends] - self.length_m, side="right")
        mean = (sums[ends + 1] - sums[starts]) / (ends + 1 - starts)
        # judged once the watch holds a whole length behind the reading
        judged = s[ends] - s[0] >= self.length_m
        dev = np.abs(mean / self.nominal_ktex - 1.0) * 100.0
        found = []
        k = 0
        while k < ends.size:
            cross = judged[k:] & ((dev[k:] <= BACK * self.limit_pct) if self.outside
                                  else (dev[k:] > self.limit_pct))  # fmt: skip
            hits = np.flatnonzero(cross)
            if hits.size == 0:
                break
            k += int(hits[0])
            self.outside = not self.outside
            found.append(CountExcursion(float(t[k]), float(s[ends[k]]), float(mean[k]),
                                        self.nominal_ktex, self.limit_pct, self.outside))  # fmt: skip
            k += 1
        keep = np.searchsorted(s, s[-1] - self.length_m, side="left") if s.size else 0
        self._s, self._x = s[keep:], x[keep:]
        self.excursions.extend(found)
        return found

    def status(self) -> dict[str, Any]:
        return {"nominal_ktex": self.nominal_ktex, "limit_pct": self.limit_pct,
                "length_m": self.length_m, "outside": self.outside,
                "excursions": len(self.excursions)}  # fmt: skip


def watch_count(delivered_m: np.ndarray, ktex: np.ndarray, time_s: np.ndarray | None,
                nominal_ktex: float) -> CountWatch:  # fmt: skip
    """A whole record through a :class:`CountWatch` (its excursions do not depend on how
    the readings are batched; a record without times: its delivered metres stand for
    them)."""
    watch = CountWatch(nominal_ktex)
    watch.push(delivered_m, ktex, delivered_m if time_s is None else time_s)
    return watch


__all__ = ["LENGTH_M", "LIMIT_PCT", "CountExcursion", "CountWatch", "nominal_count_ktex",
           "watch_count"]  # fmt: skip
