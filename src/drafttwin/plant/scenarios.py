"""Operating scenarios: the VFD set-point schedule over a recording, selectable by name.

The set-point is a machine setting, known in advance: the mechanistic model may use it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from drafttwin.errors import unknown_choice
from drafttwin.mechanics import Signal

ACCEL_TIME_S = 8.0  # assumption: VFD acceleration time (drawframe logs record it [d11])
RUN_UP_S = 2.0
"""The run-up from rest the plant simulates before a record of a running machine, s
(PlantConfig.start): quicker than the VFD's ramp to save computing (0.3 s per record
instead of 1.0 s with 8 s); it ends in the same state: after either, none of 39 healthy
machines rattles, nor machines 4711, 5 and 23 after 0.5, 1, 2 or 4 s (docs/plant.md)."""


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    from_rest: bool
    schedule: Callable[[float, float], tuple[list[float], list[float]]]

    def setpoint(self, duration_s: float, nominal_hz: float) -> Signal:
        """VFD set-point (Hz) over recording time [0, duration_s]."""
        times, hz = self.schedule(duration_s, nominal_hz)
        return Signal.from_samples(times, hz, max_dt_s=0.01)


def _steady(duration: float, f: float) -> tuple[list[float], list[float]]:
    return [0.0, duration], [f, f]


def _startup(duration: float, f: float) -> tuple[list[float], list[float]]:
    start = min(1.0, 0.1 * duration)
    return [0.0, start, start + ACCEL_TIME_S, max(duration, start + ACCEL_TIME_S + 1)], [
        0.0,
        0.0,
        f,
        f,
    ]


def _speed_change(duration: float, f: float) -> tuple[list[float], list[float]]:
    t0 = 0.5 * duration
    ramp = 0.15 * ACCEL_TIME_S  # a 15 % change ramps in proportion to the full acceleration
    return [0.0, t0, t0 + ramp, max(duration, t0 + ramp + 1)], [f, f, 0.85 * f, 0.85 * f]


def _stop(duration: float, f: float) -> tuple[list[float], list[float]]:
    t0 = 0.5 * duration
    # the VFD ramps down over its deceleration time (taken equal to the acceleration time)
    end = t0 + ACCEL_TIME_S
    return [0.0, t0, end, max(duration, end + 1)], [f, f, 0.0, 0.0]


SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        Scenario("steady", "steady running at the FA320A operating point", False, _steady),
        Scenario(
            "startup",
            f"start from rest: VFD ramp 0 -> set-point in {ACCEL_TIME_S:g} s",
            True,
            _startup,
        ),
        Scenario(
            "speed-change",
            "steady, then the delivery speed is lowered by 15 % at half time",
            False,
            _speed_change,
        ),
        Scenario(
            "stop",
            f"steady, then stopped at half time: VFD ramp set-point -> 0 in {ACCEL_TIME_S:g} s",
            False,
            _stop,
        ),
    )
}


def get_scenario(name: str) -> Scenario:
    try:
        return SCENARIOS[name]
    except KeyError:
        raise unknown_choice(f"unknown scenario '{name}'", SCENARIOS, where="--scenario") from None
