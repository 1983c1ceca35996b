"""A sensor fault sized in the unit it is injected with, from the record's samples.

A sensor rule fires on one block's features (the longest run of one repeated value, the
share of samples lost there); the fault itself spans more: a stuck encoder repeats its value
for seconds, a failing one loses a share of its samples from the onset on. Here the named
channel's samples (those the diagnosis stream keeps: the alarm's window and what precedes
it) give

* ``stuck``: the time the channel repeated one value, s (the run of identical finite values
  through the alarm block, lost rows bridged), +- one sample and the longest run a healthy
  channel shows by chance; "at least" where the run reaches the record's end;
* ``dropout``: the share of the channel's samples lost on their own (the others present)
  from the change estimate to the record's end, with its 95 % Clopper-Pearson interval.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.stats import binomtest

from drafttwin.diagnosis.locate import Cause
from drafttwin.diagnosis.residuals import CHANNELS
from drafttwin.mechanics.faults import KINDS


def size_sensor_fault(time_s: np.ndarray, y: np.ndarray, cause: Cause, alarm_s: float,
                      change_s: float, block_s: float, healthy_run: float) -> Cause:  # fmt: skip
    """``cause`` (a sensor rule's) sized on the samples ``time_s`` ``(n,)`` and ``y`` ``(n,
    5)`` (the rollers and the motor): see the module. ``alarm_s``: the end of the block whose
    rule fired; ``healthy_run``: the longest run of one value the channel showed in the
    healthy records, samples."""
    j = CHANNELS.index(cause.element)
    t = np.asarray(time_s, dtype=np.float64)
    if cause.kind == "stuck":
        return _stuck(cause, t, y[:, j], alarm_s - block_s, alarm_s, healthy_run)
    if cause.kind == "dropout":
        others = np.isfinite(np.delete(y, j, axis=1)).all(axis=1) & (t > change_s)
        n = int(others.sum())
        if n == 0:
            return cause
        k = int((others & ~np.isfinite(y[:, j])).sum())
        ci = binomtest(k, n).proportion_ci(0.95, method="exact")
        return replace(cause, severity=k / n, interval=(float(ci.low), float(ci.high)),
                       parameter=KINDS["dropout"].parameter + ", from the change on")  # fmt: skip
    return cause


def _stuck(cause: Cause, t: np.ndarray, x: np.ndarray, t0: float, t1: float,
           healthy_run: float) -> Cause:  # fmt: skip
    ok = np.flatnonzero(np.isfinite(x))
    if len(ok) < 2:
        return cause
    v, tt = x[ok], t[ok]
    new = np.concatenate([[True], v[1:] != v[:-1]])  # a run of one value, lost rows bridged
    run_id = np.cumsum(new) - 1
    starts = np.flatnonzero(new)
    ends = np.concatenate([starts[1:], [len(v)]]) - 1
    in_block = (tt > t0) & (tt <= t1)
    if not in_block.any():
        return cause
    ids = np.unique(run_id[in_block])
    r = int(ids[np.argmax(ends[ids] - starts[ids])])  # the longest run through the block
    dt = float(np.median(np.diff(t)))
    span_s = float(tt[ends[r]] - tt[starts[r]])  # lost rows inside the run count as its time
    seconds = span_s + dt
    lo = max(0.0, span_s - max(healthy_run, 0.0) * dt)
    open_end = ends[r] == len(v) - 1 or starts[r] == 0  # the record cut the run short
    return replace(cause, severity=seconds, interval=(lo, seconds if open_end else seconds + dt),
                   parameter=KINDS["stuck"].parameter,
                   bound="at_least" if open_end else None)  # fmt: skip
