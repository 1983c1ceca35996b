"""Roller speeds for the sliver tests: the FA320A's nominal surface speeds, constant or with
one roller modulated by a sine of a given wavelength on the delivered sliver."""

from __future__ import annotations

import numpy as np

from drafttwin.sliver import SurfaceSpeeds

ROLLERS = ("front", "second", "third", "back")
SURFACE_M_S = np.array([256.68, 47.79, 46.85, 39.05]) / 60.0  # FA320A nominal, m/s
GAUGES_MM = (44.0, 40.0, 46.0)


def speeds(duration_s: float, roller: str | None = None, amplitude: float = 0.0,
           wavelength_m: float = 0.2, rate_hz: float = 4000.0) -> SurfaceSpeeds:  # fmt: skip
    """Constant speeds; ``roller`` modulated by ``amplitude * sin(2 pi f t)`` with
    ``f = v_front / wavelength_m`` (the wavelength on the delivered sliver)."""
    t = np.arange(int(duration_s * rate_hz) + 1) / rate_hz
    length = t[:, None] * SURFACE_M_S[None, :]
    if roller is not None:
        k = ROLLERS.index(roller)
        f = SURFACE_M_S[0] / wavelength_m
        length[:, k] += (
            amplitude * SURFACE_M_S[k] / (2 * np.pi * f) * (1 - np.cos(2 * np.pi * f * t))
        )
    return SurfaceSpeeds(t, length, "test")


def sine_gain(density: np.ndarray, s_m: np.ndarray, wavelength_m: float) -> complex:
    """Complex amplitude ``c`` of ``r(s) = Im(c exp(i 2 pi s / wavelength))`` fitted by least
    squares to the relative density: the measured gain for a unit speed modulation."""
    r = density / density.mean() - 1.0
    kappa = 2 * np.pi / wavelength_m
    x = np.column_stack([np.sin(kappa * s_m), np.cos(kappa * s_m)])
    c, *_ = np.linalg.lstsq(x, r, rcond=None)
    return complex(c[0], c[1])
