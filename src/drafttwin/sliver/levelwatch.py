"""The leveller watched as the sliver is delivered: the live twin's recommendation of its
action point and intensity.

:class:`LevelWatch` keeps what a levelling drawframe records (delivered length, the delivery
and infeed readings, the store's length clock, time) as the readings arrive and, every
``window_m`` metres, hands the window to :func:`drafttwin.sliver.action_point.find_action_point`
with the machine's setting, fibres and delivery sensor as its description names them
(:func:`drafttwin.sliver.leveller_record.context_of`): the function and the window of
``drafttwin sliver level --max-length`` (a window is :meth:`LevellerRecord.head` of the rows
since the last one), so a replayed record gives the command's recommendation. A gap in the
readings (a lost batch) starts the window again. It recommends; it writes no setting.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drafttwin.errors import DataError, DrafttwinError
from drafttwin.sliver.action_point import SEARCH_MM, LevellingAdvice, find_action_point
from drafttwin.sliver.count import nominal_count_ktex
from drafttwin.sliver.leveller_record import LevellerRecord, LevellerSetting, context_of
from drafttwin.sliver.sensor import SliverSensor
from drafttwin.sliver.staple import StapleDiagram, resolve_fibres

WINDOW_M = 300.0
"""Delivered sliver per recommendation, m (issue 39: at most 300 m)."""


@dataclass(frozen=True, eq=False)
class LevelContext:
    """A machine's leveller as its description names it: the setting (None: none named),
    whether there is a leveller, the fibres (and where they came from) and the delivery
    sensor (None: the plant's default)."""

    setting: LevellerSetting | None
    had_leveller: bool
    staple: StapleDiagram
    fibres: str
    delivery: SliverSensor | None
    fibre_scale: float = 1.0  # an emulated machine's lumping (its ideal curve follows it)
    nominal_ktex: float | None = None  # the nominal delivered count (None: not described)

    @classmethod
    def of(cls, section: dict[str, Any]) -> LevelContext:
        """From a sidecar's ``sliver`` section or a served machine's description."""
        setting, had, described, delivery = context_of(section)
        fibres = resolve_fibres(None, described)
        scale = section.get("fibre_scale", 1.0)
        if isinstance(scale, bool) or not isinstance(scale, int | float) or not 1 <= scale <= 1e6:
            raise DataError(f"fibre_scale {scale!r} is not a number from 1 to 1e6",
                            where="description", fix="describe the sliver again")  # fmt: skip
        return cls(
            setting,
            had,
            fibres.staple,
            fibres.source,
            delivery,
            float(scale),
            nominal_count_ktex(section),
        )

    def to_dict(self) -> dict[str, Any]:
        s = self.setting
        return {"leveller": self.had_leveller,
                "action_point_mm": None if s is None else s.action_point_mm,
                "intensity": None if s is None else s.intensity,
                "reference_ktex": None if s is None else s.reference_ktex,
                "fibres": self.fibres}  # fmt: skip


@dataclass
class LevelWatch:
    """Windows of a machine's levelling record, and the recommendation from each."""

    context: LevelContext
    window_m: float = WINDOW_M
    search_mm: float = SEARCH_MM
    advice: LevellingAdvice | None = None
    window: tuple[float, float] | None = None  # the advice's first and last delivered m
    checks: int = 0
    gaps: int = 0
    failed: str | None = None  # why the last window gave no recommendation
    took_s: float | None = None  # how long the last window took to compute (wall clock)
    _cols: list[list[np.ndarray]] = field(default_factory=lambda: [[] for _ in range(5)])
    _first_m: float = math.nan
    _last_m: float = math.nan
    _step_m: float = math.nan

    @property
    def recommends(self) -> bool:
        """The standing advice places the action point (what ``sliver level`` recommends);
        a window that does not (``identifiable`` false: the least CV on the search's edge, an
        infeed reading without information) recommends nothing."""
        return self.advice is not None and self.advice.identifiable

    @property
    def state(self) -> str:
        """``no leveller`` (the description names no setting), ``collecting``,
        ``recommending`` (an advice stands that places the action point) or ``not placed``
        (the last window's advice does not place it: nothing is recommended)."""
        if self.context.setting is None:
            return "no leveller"
        if self.advice is None:
            return "collecting"
        return "recommending" if self.recommends else "not placed"

    @property
    def collected_m(self) -> float:
        """Sliver collected toward the next window, m."""
        return 0.0 if math.isnan(self._first_m) else self._last_m - self._first_m

    def push(self, delivered_m: np.ndarray, ktex: np.ndarray, time_s: np.ndarray,
             infeed_ktex: np.ndarray, fed_length_m: np.ndarray) -> None:  # fmt: skip
        """Readings in delivery order (a batch); a gap before them starts the window again."""
        if self.context.setting is None or delivered_m.size == 0:
            return
        cols = (delivered_m, ktex, time_s, infeed_ktex, fed_length_m)
        if not all(np.all(np.isfinite(c)) for c in cols):
            self._restart()  # a machine without infeed readings: nothing to level on
            return
        if delivered_m.size > 1 and math.isnan(self._step_m):
            self._step_m = float(np.median(np.diff(delivered_m)))
        if not math.isnan(self._last_m):
            jump = float(delivered_m[0]) - self._last_m
            if not 0 < jump <= 1.5 * self._step_m:
                self.gaps += 1
                self._restart()
        for store, c in zip(self._cols, cols, strict=True):
            store.append(np.asarray(c, dtype=np.float64))
        if math.isnan(self._first_m):
            self._first_m = float(delivered_m[0])
        self._last_m = float(delivered_m[-1])

    def _restart(self) -> None:
        self._cols = [[] for _ in range(5)]
        self._first_m = self._last_m = math.nan

    def due(self) -> bool:
        """A whole window is collected."""
        return self.context.setting is not None and self.collected_m >= self.window_m

    def take(self) -> LevellerRecord:
        """The window (the first ``window_m`` metres collected), removed from what is kept."""
        s, x, t, inf, fed = (np.concatenate(c) for c in self._cols)
        record = LevellerRecord(s, x, inf, fed, t, "the live sliver").head(self.window_m)
        n = record.delivered_length_m.size
        self._cols = [[a[n:]] for a in (s, x, t, inf, fed)]
        self._first_m = float(s[n]) if n < s.size else math.nan
        self._last_m = self._last_m if n < s.size else math.nan
        return record

    def check(self, record: LevellerRecord) -> LevellingAdvice | str:
        """The recommendation from a window (``sliver level``'s own function), or why the
        window says nothing; changes nothing (a worker thread may run it)."""
        assert self.context.setting is not None
        try:
            return find_action_point(record, self.context.setting, self.context.staple,
                                     self.context.delivery, search_mm=self.search_mm)  # fmt: skip
        except DrafttwinError as exc:
            return exc.problem

    def accept(self, record: LevellerRecord, result: LevellingAdvice | str) -> None:
        """Take a window's result: the standing recommendation, or the reason for none."""
        if isinstance(result, str):
            self.failed = result
            return
        self.advice, self.failed = result, None
        self.window = (float(record.delivered_length_m[0]), float(record.delivered_length_m[-1]))
        self.checks += 1

    def summary(self) -> dict[str, Any]:
        """State, setting, progress and the standing recommendation (JSON-able)."""
        return {"state": self.state, "setting": self.context.to_dict(),
                "window_m": self.window_m, "collected_m": round(self.collected_m, 3),
                "checks": self.checks, "gaps": self.gaps, "failed": self.failed,
                "took_s": None if self.took_s is None else round(self.took_s, 3),
                "window": None if self.window is None else list(self.window),
                "says": self.text(),
                "advice": None if self.advice is None else self.advice.to_dict()}  # fmt: skip

    def text(self) -> str:
        """The standing recommendation in one line (an event)."""
        a = self.advice
        if a is None:
            return f"leveller: no recommendation ({self.failed or 'collecting'})"
        lo, hi = a.action_point_interval_mm
        current = ("none" if a.current_action_point_mm is None
                   else f"{a.current_action_point_mm:.1f} mm")  # fmt: skip
        notes = "".join(f"; {n}" for n in a.notes)
        if not a.identifiable:
            return (f"leveller: no recommendation: these {a.metres_used:.0f} m do not say where "
                    f"the action point is (current {current}, {a.current_intensity:.2f}, CV "
                    f"{a.current.cv_pct:.3f} %){notes}")  # fmt: skip
        return (f"leveller: action point {a.recommended_action_point_mm:.1f} mm (95 % "
                f"{lo:.1f}-{hi:.1f}), intensity {a.recommended_intensity:.2f} recommended "
                f"(current {current}, {a.current_intensity:.2f}): CV {a.current.cv_pct:.3f} % "
                f"-> {a.recommended.cv_pct:.3f} % expected, from {a.metres_used:.0f} m; "
                f"the twin writes no setting{notes}")  # fmt: skip


__all__ = ["SEARCH_MM", "WINDOW_M", "LevelContext", "LevelWatch"]
