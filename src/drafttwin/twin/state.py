"""What the twin knows of each machine (its state, the page's rows, its fault detector and
identity), as the page and /api/status show it."""

from __future__ import annotations

import json
import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drafttwin.sliver.levelwatch import LevelWatch
from drafttwin.sliver.watch import SliverWatch
from drafttwin.twin.faultwatch import LiveFaultWatch
from drafttwin.twin.live import MachineTwin
from drafttwin.twin.sources.mapping import MachineMap
from drafttwin.twin.store.baselines import Baseline
from drafttwin.twin.store.db import EventRow, SampleRow
from drafttwin.wire.identity import MachineIdentity

ALARM_KINDS = ("fault", "fault-cause", "sensor-fault", "sliver-chimney", "sliver-count")
"""Events that are alarms (``/api/alarms``); the others are ``/api/events``."""
ALARMS_KEPT = 1000
"""A machine's newest alarms kept in memory (a twin without --store answers from them)."""
EVENTS_KEPT = 200
"""... and its newest other events (gaps, reconnects: a lossy link makes thousands)."""
LATENCY_WINDOW = 20_000
"""Latencies kept for the percentiles (sample received -> stored and pushed)."""
HISTORY_ROWS = 3000
"""Rows per machine kept in memory for the page (30 s at 100 Hz)."""


@dataclass
class MachineState:
    """What the page and /api/status show for a machine."""

    twin: MachineTwin
    mapping: MachineMap
    source: str
    state: str = "connecting"
    received: int = 0
    dropped: int = 0
    skipped: int = 0  # already in the store (a restart resumed after them)
    last_wall: float = 0.0
    waiting_since: float | None = None  # the source connected; no sample of this machine yet
    resume_after_us: int | None = None
    recent: deque[SampleRow] = field(default_factory=lambda: deque(maxlen=HISTORY_ROWS))
    # without a store, what /api/alarms and /api/events answer; apart, so that a flood of
    # gap events cannot push the alarms out (one deque of 200 had lost the first alarm)
    alarms: deque[EventRow] = field(default_factory=lambda: deque(maxlen=ALARMS_KEPT))
    events: deque[EventRow] = field(default_factory=lambda: deque(maxlen=EVENTS_KEPT))
    watch: LiveFaultWatch | None = None  # the fault detector, when the model has one
    model_key: str = ""  # the model file (the locator's key for its diagnoser)
    model_sha256: str = ""
    identity: MachineIdentity | None = None  # who the machine is, when its source says
    baseline: Baseline | None = None  # what it learned (stored with its identity)
    prior: dict[str, Any] | None = None  # the detector file it learns on top of
    refused: str | None = None  # why a stored baseline was not used
    faults: int = 0
    last_fault: EventRow | None = None  # the latest alarm or its cause (status, hall page)
    sliver: SliverWatch | None = None  # the sliver channel's watch, once the source sends one
    sliver_busy: bool = False  # a check runs in the worker thread
    sliver_seq: int = -1  # the last sliver batch taken (a repeated one is dropped)
    sliver_repeated: int = 0
    level: LevelWatch | None = None  # the leveller's windows, once the source describes it
    level_busy: bool = False  # a window runs in the leveller's worker
    # source time -> received (wall clock), s: the transport's share of the latency, for
    # live sources (a replay's times are the file's)
    transport_s: deque[float] = field(default_factory=lambda: deque(maxlen=LATENCY_WINDOW))
    newest_source_s: float = math.nan  # the newest processed sample's source time

    def transport_ms(self) -> dict[str, float] | None:
        if not self.transport_s or self.source.startswith("replay"):
            return None
        lat = np.asarray(self.transport_s) * 1e3
        return {"p50": float(np.percentile(lat, 50)), "p99": float(np.percentile(lat, 99))}

    def data_age_s(self) -> float | None:
        """Wall clock minus the newest sample's source time (live sources only)."""
        if self.source.startswith("replay") or not math.isfinite(self.newest_source_s):
            return None
        return time.time() - self.newest_source_s


def detector_state(st: MachineState) -> dict[str, Any]:
    """A machine's fault detector as status shows it: ``none``, ``learning`` (how far, how
    long still) or ``watching`` (its baseline: when and over how long it was learned, the
    identity it was learned on, the prior it was combined with)."""
    w = st.watch
    if w is None:
        return {"state": "none"}
    out: dict[str, Any] = {"state": "learning" if w.learning else "watching",
                           "learn_s": w.learn_s, "prior": None if st.prior is None else st.prior["file"]}  # fmt: skip
    if w.learning:
        out.update({"progress": round(w.learn_progress, 4), "left_s": round(w.learn_left_s, 1)})
    elif st.baseline is not None:
        out["baseline"] = st.baseline.summary()
    return out


def fault_summary(ev: EventRow | None) -> dict[str, Any] | None:
    """An alarm event as status shows it: its kind and time, and its detail parsed."""
    if ev is None:
        return None
    try:
        detail = json.loads(ev.detail)
    except ValueError:
        detail = {"text": ev.detail}
    return {"kind": ev.kind, "time": ev.ts_us / 1e6, **detail}


__all__ = ["HISTORY_ROWS", "LATENCY_WINDOW", "MachineState", "detector_state", "fault_summary"]
