"""Watching the sliver as it is delivered: running count and CV, the spectrogram every few
hundred metres, an alarm when a chimney appears, named with its element.

:class:`SliverWatch` takes the delivery sensor's readings in order (any number at a time) and
keeps the last ``window_m`` metres; every ``every_m`` metres it diagnoses that window
(:func:`drafttwin.sliver.diagnose.diagnose_sliver`) and raises a :class:`SliverAlarm` the first
time a chimney appears at a wavelength where none was before (the watch remembers each
channel it has alarmed on, so one fault alarms once). The offline ``diagnose`` and the live
twin use the same watch.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drafttwin.mechanics import DriveTrain
from drafttwin.sliver.count import CountExcursion, CountWatch
from drafttwin.sliver.diagnose import SliverDiagnosis, diagnose_sliver, reference_spectrogram
from drafttwin.sliver.drafting import DraftingZones
from drafttwin.sliver.record import Sliver
from drafttwin.sliver.reference import SliverReference
from drafttwin.sliver.staple import StapleDiagram
from drafttwin.sliver.wavelengths import wavelength_table


@dataclass(frozen=True)
class SliverAlarm:
    """A chimney that appeared: when, where on the sliver, and its first cause."""

    time_s: float
    delivered_m: float
    wavelength_m: float
    amplitude_pct: float
    base_pct: float
    element: str
    lookalikes: tuple[str, ...]
    verdict: str

    def to_dict(self) -> dict[str, Any]:
        return dict(vars(self))


@dataclass
class SliverWatch:
    """Incremental watch of one machine's delivered sliver (see the module docstring)."""

    train: DriveTrain
    staple: StapleDiagram
    zones: DraftingZones = field(default_factory=DraftingZones)
    window_m: float = 100.0
    every_m: float = 50.0
    sensor_length_m: float = 0.0
    fibre_scale: float = 1.0
    """Fibres an emulator lumped into one (Martindale's limit and the ideal curve follow it)."""
    reference: Sliver | SliverReference | None = None
    """A healthy sliver of this machine (or the lines it gave): its own lines do not alarm
    (only new chimneys)."""
    learning: bool = False
    """While True (the machine learns its healthy state) each window's spectrogram goes into
    :attr:`learned` and no chimney alarms; after :meth:`end_learning` the windows are
    judged by it."""
    learned: SliverReference | None = None
    """The machine's own lines from the windows seen while learning (None: none yet)."""
    nominal_ktex: float | None = None
    """The machine's nominal delivered count: the count's limit is watched against it
    (:class:`~drafttwin.sliver.count.CountWatch`; None: not watched)."""
    _s: list[np.ndarray] = field(default_factory=list, repr=False)
    _x: list[np.ndarray] = field(default_factory=list, repr=False)
    _t: list[np.ndarray] = field(default_factory=list, repr=False)
    _sum: float = 0.0
    _sum2: float = 0.0
    _n: int = 0
    _next_m: float = math.nan
    _alarmed: set[int] = field(default_factory=set, repr=False)
    alarms: list[SliverAlarm] = field(default_factory=list)
    last: SliverDiagnosis | None = None

    def __post_init__(self) -> None:
        self._lock = threading.Lock()
        self.count: CountWatch | None = None
        self._count_news: list[CountExcursion] = []
        self.hold_count(self.nominal_ktex)
        self._table = wavelength_table(self.train)
        self._reference = (None if self.reference is None else
                           reference_spectrogram(self.reference, self.staple,
                                                 self.sensor_length_m))  # fmt: skip

    @property
    def own_lines(self) -> SliverReference | None:
        """The reference the watch judges by (None: every chimney is new): the lines it
        learned once its learning ended, else the one it was given."""
        ended = not self.learning and math.isfinite(self._learn_until_m)
        return self.learned if ended and self.learned is not None else self._reference

    def end_learning(self) -> None:
        """The machine finished learning: the windows delivered by now are its own lines
        (a window still being checked counts too), the later ones are judged by them."""
        self.learning = False
        self._learn_until_m = self._last_m if math.isfinite(self._last_m) else -math.inf

    @property
    def learned_final(self) -> bool:
        """Learning ended and every window delivered before its end is in :attr:`learned`."""
        until = self._learn_until_m
        return (not self.learning and math.isfinite(until)
                and not (self._next_m <= until))  # fmt: skip

    def relearn(self) -> None:
        """An operator's relearn (after maintenance): the machine's lines are learned anew."""
        self.learned, self._reference, self.learning = None, None, True
        self._learn_until_m = math.nan
        self._alarmed.clear()

    def hold_count(self, nominal_ktex: float | None) -> None:
        """Watch the count against ``nominal_ktex`` from the next reading on (a machine that
        describes itself after its first readings); None or the same nominal changes
        nothing."""
        if nominal_ktex is not None and (self.count is None
                                         or self.count.nominal_ktex != nominal_ktex):  # fmt: skip
            self.nominal_ktex = nominal_ktex
            self.count = CountWatch(nominal_ktex)

    def take_count_excursions(self) -> list[CountExcursion]:
        """The count's excursions since the last call (the twin's events)."""
        news, self._count_news = self._count_news, []
        return news

    @property
    def count_ktex(self) -> float:
        """Running mean linear density of everything seen, ktex."""
        return self._sum / self._n if self._n else math.nan

    @property
    def cv_pct(self) -> float:
        """Running CV of every reading seen, %."""
        if self._n < 2:
            return math.nan
        mean = self._sum / self._n
        return 100 * math.sqrt(max(self._sum2 / self._n - mean * mean, 0.0)) / mean

    def push(self, delivered_m: Sequence[float] | np.ndarray, ktex: Sequence[float] | np.ndarray,
             time_s: Sequence[float] | np.ndarray) -> list[SliverAlarm]:  # fmt: skip
        """Add readings in delivery order; returns the alarms they raised."""
        s, x, t = (np.asarray(a, dtype=np.float64) for a in (delivered_m, ktex, time_s))
        ok = np.isfinite(s) & np.isfinite(x) & np.isfinite(t) & (x > 0)
        s, x, t = s[ok], x[ok], t[ok]
        if s.size == 0:
            return []
        with self._lock:  # a live twin's check reads and trims them in its worker thread
            self._s.append(s)
            self._x.append(x)
            self._t.append(t)
        self._sum += float(x.sum())
        self._sum2 += float(np.dot(x, x))
        self._n += x.size
        if math.isnan(self._next_m):
            self._next_m = float(s[0]) + self.window_m
        self._last_m = float(s[-1])
        if self.count is not None:
            self._count_news += self.count.push(s, x, t)
        return self.check() if self.checks_now else []

    checks_now: bool = True
    """``push`` runs the due checks itself; a live twin sets it False and runs :meth:`check`
    in a worker thread when :meth:`due` says so (a check takes a fraction of a second)."""
    _last_m: float = math.nan
    _learn_until_m: float = math.nan  # delivered metres when learning ended

    def due(self) -> bool:
        """A window is complete and not yet checked."""
        return not math.isnan(self._next_m) and self._last_m >= self._next_m

    def check(self) -> list[SliverAlarm]:
        """Run every due check; returns the alarms raised."""
        raised: list[SliverAlarm] = []
        while self.due():
            raised += self._check(self._next_m)
            self._next_m += self.every_m
        return raised

    def summary(self) -> dict[str, Any]:
        """Running count and CV, the alarms, and the last window's chimneys (for a page)."""
        last = self.last
        return {"count_ktex": self.count_ktex, "cv_pct": self.cv_pct,
                "delivered_m": self._last_m, "alarms": len(self.alarms),
                "last_alarm": self.alarms[-1].to_dict() if self.alarms else None,
                "chimneys": [] if last is None else [
                    {"wavelength_m": c.wavelength_m, "amplitude_pct": c.amplitude_pct,
                     "element": c.candidates[0].element if c.candidates else "feed"}
                    for c in last.causes],
                "learning": self.learning,
                "own_lines": [{"wavelength_m": c.wavelength_m, "amplitude_pct": c.amplitude_pct,
                               "element": c.candidates[0].element if c.candidates else "feed"}
                              for c in (last.known if last is not None else [])],
                "learned": None if (ref := self.own_lines) is None else
                {"metres": ref.metres, "windows": ref.windows},
                "count_limit": None if self.count is None else self.count.status()}  # fmt: skip

    def text(self, alarm: SliverAlarm) -> str:
        """One line for an event list."""
        like = f" (look-alikes {', '.join(alarm.lookalikes)})" if alarm.lookalikes else ""
        return (
            f"sliver chimney at {alarm.wavelength_m * 100:.2f} cm, "
            f"{alarm.amplitude_pct:.3f} % (base {alarm.base_pct:.3f} %) after "
            f"{alarm.delivered_m:.0f} m: {alarm.element}{like}"
        )

    def _check(self, end_m: float) -> list[SliverAlarm]:
        # once: the twin's loop may end the learning meanwhile (by delivered metres, so a
        # window delivered while the machine learned is learned whenever it is checked)
        learning = self.learning or end_m <= self._learn_until_m
        with self._lock:  # readings pushed meanwhile are neither torn nor lost
            s, x, t = (np.concatenate(a) for a in (self._s, self._x, self._t))
            keep = s > end_m - self.window_m - 1.0  # drop what no window needs again
            self._s, self._x, self._t = [s[keep]], [x[keep]], [t[keep]]
        inside = (s > end_m - self.window_m) & (s <= end_m)
        if inside.sum() < 100:
            return []
        step = float(np.median(np.diff(s[inside])))
        record = Sliver(x[inside], step, start_m=float(s[inside][0]) - step / 2,
                        fibre_scale=self.fibre_scale,
                        time_s=t[inside], staple=self.staple)  # fmt: skip
        dx = diagnose_sliver(record, self.train, self.staple, self.zones,
                             sensor_length_m=self.sensor_length_m, table=self._table,
                             reference=None if learning else self.own_lines)  # fmt: skip
        self.last = dx
        if learning:  # the machine's own lines, not alarms
            self.learned = (SliverReference.of(dx.spectrogram) if self.learned is None
                            else self.learned.add(dx.spectrogram, self.every_m))  # fmt: skip
            return []
        raised = []
        for c in dx.causes:
            channel = int(round(10 * math.log2(c.wavelength_m / 0.01)))
            if channel in self._alarmed:
                continue
            self._alarmed.add(channel)
            top = c.candidates[0] if c.candidates and c.candidates[0].plausible else None
            raised.append(SliverAlarm(float(t[inside][-1]), end_m, c.wavelength_m,
                                      c.amplitude_pct, c.base_pct,
                                      top.element if top else "feed",
                                      top.lookalikes if top else (), c.verdict))  # fmt: skip
        self.alarms += raised
        return raised
