"""Limits on work that would never end: refuse it at once instead of hanging.

A fixed-step simulation of ``duration / dt`` steps with ``dt = 1e-12`` would run for days;
a NaN or infinite time would loop forever or make arrays of absurd size. These checks run
before any integration starts (mechanics and plant call them with the numbers they will use).
"""

from __future__ import annotations

import math

from drafttwin.errors import ConfigError

#: most RK4 steps one simulation may take (about 20 minutes of the full FA320A train)
MAX_RK4_STEPS = 1e9


def check_time(value_s: float, name: str, *, allow_zero: bool = False) -> None:
    """Refuse a time that is NaN, infinite or negative (or zero unless ``allow_zero``)."""
    ok = math.isfinite(value_s) and (value_s >= 0 if allow_zero else value_s > 0)
    if not ok:
        bound = ">= 0" if allow_zero else "> 0"
        raise ConfigError(f"{value_s!r} s: must be finite and {bound}", where=name,
                          fix=f"give {name} a finite time {bound} s")  # fmt: skip


def check_rk4_steps(duration_s: float, dt_s: float, *, settle_s: float = 0.0,
                    where: str = "dt") -> int:  # fmt: skip
    """The number of RK4 steps of a run; refuse more than :data:`MAX_RK4_STEPS`."""
    check_time(duration_s, "duration", allow_zero=True)
    check_time(settle_s, "settle", allow_zero=True)
    check_time(dt_s, where)
    steps = (duration_s + settle_s) / dt_s
    if steps > MAX_RK4_STEPS:
        raise ConfigError(
            f"{duration_s + settle_s:g} s at a step of {dt_s:g} s is {steps:.3g} RK4 steps, "
            f"more than the {MAX_RK4_STEPS:.0e} a run may take (it would not end)",
            where=where,
            fix=f"use a step >= {(duration_s + settle_s) / MAX_RK4_STEPS:.2g} s or a shorter "
            "duration",
        )
    return int(math.ceil(steps))


#: most output samples (rows) one run may produce (1e8 rows: about 6 GB of CSV)
MAX_OUTPUT_SAMPLES = 1e8


def check_samples(duration_s: float, rate_hz: float, *, where: str = "duration, rate") -> int:
    """The number of output samples of a run; refuse more than :data:`MAX_OUTPUT_SAMPLES`."""
    check_time(duration_s, "duration", allow_zero=True)
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ConfigError(f"{rate_hz!r} Hz: must be finite and > 0", where=where)
    samples = duration_s * rate_hz
    if samples > MAX_OUTPUT_SAMPLES:
        raise ConfigError(
            f"{duration_s:g} s at {rate_hz:g} Hz is {samples:.3g} samples, more than the "
            f"{MAX_OUTPUT_SAMPLES:.0e} a run may write",
            where=where,
            fix="a shorter duration or a lower rate (or several runs)",
        )
    return int(round(samples))
