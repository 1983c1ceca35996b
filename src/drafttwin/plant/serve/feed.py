"""The served machines' physics, computed ahead of the wall clock in a worker thread.

Where a served plant's time goes (FA320A, full physics, 100 Hz): one kernel call of 500 RK4
steps per sample, about 1.3-1.8 ms of a core per machine; the VFD ramp, the encoders and the
rest of the plant's Python about 0.15 ms; each OPC UA write 12-32 us (seven per machine and
sample). Stepped inside the event loop, the physics held the loop for each sample, so a loop
that got a few milliseconds less than its share (two busy processes beside it, a subscribed
client) published late, and a loop that got less than its share for a while fell behind for
good (6.2 s behind after two minutes, issue 37).

So a worker thread computes every machine's physics up to :data:`AHEAD_S` ahead of the samples
published (refilled a chunk at a time, when a chunk has been taken), and the loop only
measures and publishes each sample at its wall-clock time. The numba kernel leaves the GIL
while it integrates, so the worker runs beside the loop (on the other core when there is one),
and a hiccup of the loop or of the worker shorter than the look-ahead makes nothing late. The
samples are those of stepping one by one, bit for bit (:mod:`drafttwin.plant.live`); a set-point
written takes effect from the next sample computed, at most :data:`AHEAD_S` later than
without the look-ahead. Lateness is measured as before: each sample's publishing time against
its own time (:class:`~drafttwin.plant.serve.pacing.Pacing`).
"""

from __future__ import annotations

import threading
from collections.abc import Sequence

from drafttwin.plant.live import LivePlant

AHEAD_S = 0.2
"""Most machine time computed ahead of the samples published, s."""
CHUNK_S = 0.05
"""The worker refills when this much has been taken, s (a chunk of samples per wake-up)."""


class Feed:
    """Computes ``plants``' physics ahead in a worker thread (use as ``with``).

    Args:
        plants: the served machines (one worker integrates them all, in turn, sample by sample).
        rate_hz: sample rate, Hz.
        ahead_s: most machine time computed ahead, s (0: no worker, the loop computes).
        chunk_s: the refill's size, s.
    """

    def __init__(self, plants: Sequence[LivePlant], rate_hz: float, *, ahead_s: float = AHEAD_S,
                 chunk_s: float = CHUNK_S) -> None:  # fmt: skip
        self.plants = list(plants)
        self.depth = max(0, round(ahead_s * rate_hz))
        self.chunk = min(self.depth, max(1, round(chunk_s * rate_hz)))
        self.end: int | None = None  # no physics computed beyond this sample (the duration)
        self.error: BaseException | None = None
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def __enter__(self) -> Feed:
        for p in self.plants:  # the look-ahead filled before the clock starts
            p.compute(self.depth)
        if self.depth > 0:
            self._thread = threading.Thread(target=self._work, name="drafttwin-physics",
                                            daemon=True)  # fmt: skip
            self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop the worker: it ends after the sample it is computing (a few milliseconds)."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def _wanted(self, p: LivePlant) -> bool:
        return p.computed - p.seq < self.depth and (self.end is None or p.computed < self.end)

    def _work(self) -> None:
        """Worker thread: fill every plant up to the look-ahead, one sample of each in turn,
        then sleep until a chunk has been taken."""
        try:
            while not self._stop.is_set():
                busy = False
                for p in self.plants:
                    if self._wanted(p) and not self._stop.is_set():
                        p.compute(1)
                        busy = True
                if not busy:
                    self._wake.wait()
                    self._wake.clear()
        except Exception as exc:  # said in the loop at the next sample (took())
            self.error = exc

    def took(self) -> None:
        """The loop measured a sample of every plant: wake the worker when a chunk is free."""
        if self.error is not None:
            error, self.error = self.error, None
            raise error
        p = self.plants[0]
        if p.computed - p.seq <= self.depth - self.chunk:
            self._wake.set()


__all__ = ["AHEAD_S", "CHUNK_S", "Feed"]
