"""Keeping a served plant on the wall clock, and saying when it cannot.

Sample ``k`` is due at ``t0 + k / rate`` (wall clock) and carries that time as its source
time. A loop that falls behind (a busy machine) publishes its samples late, each still with
its own time, and says so: the lag (wall time at publishing minus source time) goes to the
plant's log and to the transport (OPC UA ``lag_s``, the payload's ``lag_s``), a warning line
(at most one per ``warn_every_s``) and the summary.

By default that is all: every sample is published, so the counter has no gaps and a twin's
store can be audited sample by sample; a plant that cannot keep up drifts behind, but says so.
With ``max_lag_s`` (``plant serve --max-lag``) it skips instead once it is that far behind:
the machines integrate the missed span (:meth:`~drafttwin.plant.live.LivePlant.skip`) and
the counter jumps, so the plant's clock stays the wall clock and a twin sees a gap it counts
as dropped samples. When even that falls behind, the physics alone is slower than real time
on this machine, and the warning says so.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from drafttwin.plant.live import LivePlant

DEFAULT_WARN_LAG_S = 1.0
"""Behind the wall clock by more than this, a served plant warns, s."""
WARN_EVERY_S = 10.0
"""Least time between two lateness warnings, s."""


@dataclass
class Pacing:
    """The schedule of a served plant and what it measured of its lateness.

    ``warn(text)`` is called (rate-limited) when the loop is more than ``warn_lag_s`` late.
    ``max_lag_s``: skip samples once that far behind (``inf``, the default: never skip)."""

    rate_hz: float
    max_lag_s: float = math.inf
    warn_lag_s: float = DEFAULT_WARN_LAG_S
    warn: Callable[[str], None] | None = None
    warn_every_s: float = WARN_EVERY_S
    end_tick: int | None = None  # the last tick of a run of fixed duration
    t0_s: float = 0.0
    tick: int = 0
    lag_s: float = 0.0
    max_seen_lag_s: float = 0.0
    late_ticks: int = 0  # published more than one sample period after their time
    skipped: int = 0  # samples never measured (caught up)
    warnings: int = 0
    physics_bound: bool = False  # still behind right after a catch-up: the physics is too slow
    _skipped_last: bool = False
    _start_mono: float = 0.0
    _last_warn: float = field(default=-math.inf)

    def start(self) -> float:
        """Start the clock now; returns ``t0_s`` (the machines' time origin)."""
        self.t0_s = time.time()
        self._start_mono = time.monotonic()
        return self.t0_s

    def now_s(self) -> float:
        """The wall clock, epoch s, on the monotonic clock's steps (immune to clock setting)."""
        return self.t0_s + (time.monotonic() - self._start_mono)

    async def next_tick(self) -> int:
        """Wait for the next sample instant; returns how many samples to skip first (0 unless
        the loop is more than ``max_lag_s`` behind)."""
        self.tick += 1
        delay = self._start_mono + self.tick / self.rate_hz - time.monotonic()
        # always yield: a loop behind schedule must still let the others run
        await asyncio.sleep(max(delay, 0.0))
        behind = -delay
        skip = 0
        if behind > self.max_lag_s:
            skip = int(behind * self.rate_hz)
            if self.end_tick is not None:  # the last sample of a timed run is published
                skip = max(0, min(skip, self.end_tick - self.tick))
            self.tick += skip
            self.skipped += skip
        self._skipped_last = skip > 0
        return skip

    def published(self, sample_time_s: float) -> float:
        """Record that the sample of ``sample_time_s`` went out now; returns its lag, s."""
        lag = self.now_s() - sample_time_s
        self.lag_s = lag
        self.max_seen_lag_s = max(self.max_seen_lag_s, lag)
        if lag > 1.0 / self.rate_hz:
            self.late_ticks += 1
        if self._skipped_last and lag > self.max_lag_s:
            self.physics_bound = True
        if lag > self.warn_lag_s:
            mono = time.monotonic()
            if mono - self._last_warn >= self.warn_every_s:
                self._last_warn = mono
                self.warnings += 1
                if self.warn is not None:
                    self.warn(self._late_text(lag))
        return lag

    def _late_text(self, lag: float) -> str:
        text = f"behind the wall clock by {lag:.2f} s"
        if math.isinf(self.max_lag_s):
            text += " (every sample is still published, late; --max-lag skips instead)"
        else:
            text += f" (skipped {self.skipped} samples so far)"
        if self.physics_bound:
            text += ("; the physics alone is slower than real time here: use --physics "
                     "reduced, fewer machines or a lower --rate")  # fmt: skip
        return text

    def summary(self) -> str:
        """One line for the end of a run."""
        return (f"timing: {self.late_ticks} samples published late (> 1 sample period), "
                f"max lag {self.max_seen_lag_s:.3f} s, {self.skipped} samples skipped, "
                f"{self.warnings} warnings"
                + ("; the physics was slower than real time" if self.physics_bound else ""))  # fmt: skip


async def catch_up(plants: Sequence[LivePlant], n: int, rate_hz: float) -> None:
    """Skip ``n`` samples of every plant, one second of machine time per integration, letting
    the event loop serve its clients in between (a long catch-up must not block them)."""
    chunk = max(1, round(rate_hz))
    while n > 0:
        k = min(n, chunk)
        for p in plants:
            p.skip(k)
        n -= k
        if n:
            await asyncio.sleep(0)


__all__ = ["DEFAULT_WARN_LAG_S", "WARN_EVERY_S", "Pacing", "catch_up"]
