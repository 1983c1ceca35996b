"""Roller surface speeds from the drive train's physics.

The physics is simulated at a fine output rate (2 kHz: 2 mm of sliver per sample at the
FA320A's delivery), so its mesh, chain and once-per-revolution lines reach the sliver as the
drive makes them, not aliased into a 100 Hz encoder's band.
"""

from __future__ import annotations

from collections.abc import Callable

from drafttwin.errors import ConfigError
from drafttwin.mechanics import DriveTrain, simulate
from drafttwin.sliver.speeds import ROLLER_ORDER, SurfaceSpeeds

DETAIL_RATE_HZ = 2000.0


def roller_diameters_mm(train: DriveTrain) -> dict[str, float]:
    """Bottom-roller diameters (mm) by name; all four must be declared."""
    found = {str(r.name): float(r.diameter_mm) for r in train.spec.roller}
    missing = [r for r in ROLLER_ORDER if r not in found]
    if missing:
        raise ConfigError(f"the train declares no roller {', '.join(missing)}: the sliver needs "
                          "front, second, third and back", source=train.source,
                          where="[[roller]]",
                          fix="a drafting train with these four rollers, e.g. --preset fa320a")  # fmt: skip
    return found


def physics_speeds(train: DriveTrain, duration_s: float, rate_hz: float = DETAIL_RATE_HZ,
                   progress: Callable[[float], None] | None = None) -> SurfaceSpeeds:  # fmt: skip
    """Surface speeds of the train's rollers simulated for ``duration_s`` at ``rate_hz``."""
    diameters = roller_diameters_mm(train)  # refuse a train without the four rollers first
    res = simulate(train, duration_s, output_rate_hz=rate_hz, progress=progress)
    return SurfaceSpeeds.from_rpm(res.time_s, res.roller_rpm(ROLLER_ORDER), diameters,
                                  f"physics of {train.spec.train.name} at {rate_hz:g} Hz")  # fmt: skip


def with_physics_detail(coarse: SurfaceSpeeds, train: DriveTrain,
                        rate_hz: float = DETAIL_RATE_HZ) -> SurfaceSpeeds:  # fmt: skip
    """``coarse`` speeds (a 100 Hz record or prediction) with the physics' content within
    each of their intervals (:meth:`SurfaceSpeeds.with_detail`). The physics runs at the
    train's own set-point for the record's duration: the lines' amplitudes come from it,
    their phases cannot (no record holds them)."""
    if rate_hz <= 1.0 / coarse.step_s:
        return coarse
    detail = physics_speeds(train, coarse.duration_s, rate_hz)
    shifted = SurfaceSpeeds(detail.time_s - detail.time_s[0] + coarse.time_s[0],
                            detail.length_m, detail.source)  # fmt: skip
    return coarse.with_detail(shifted)
