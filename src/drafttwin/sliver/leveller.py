"""An open-loop autoleveller: the infeed scanning rollers measure, the main draft levels.

The scanning rollers read the fed slivers' thickness; a length-clocked store delays each
reading until that material reaches the action point; there the rollers upstream of the main
draft (second, third and back together, so the break draft stays) run slower by the measured
excess, and the main draft takes it out (research/sliver.md section 6: Rieter RSB, levelling
through the main draft, delivery speed constant).

In ideal drafting the main draft acts where a fibre's leading end reaches the front nip, so
the true action point is the fed position whose leading ends arrive at the front nip now.
``action_offset_mm`` (fed sliver) is the setting's error: positive applies each correction
to material that far behind the right one. With a perfect setting and full intensity a step
in the feed (a sliver running out) is levelled but for the sensor's averaging length; the
CV against the offset is V-shaped around the true action point (check T10).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drafttwin.errors import ConfigError

UPSTREAM = (1, 2, 3)
"""Columns of the surface array (second, third, back) that the leveller drives."""
PASSES = 3
MIN_FACTOR, MAX_FACTOR = 0.5, 2.0
"""The feeding rollers' speed range under the leveller (a servo's range)."""
"""Fixed-point passes: the correction moves the material it is computed from."""


@dataclass(frozen=True)
class Autoleveller:
    """Open-loop levelling through the main draft.

    Attributes:
        intensity: fraction of the measured excess corrected (1: all of it).
        action_offset_mm: error of the action point's setting, mm of fed sliver.
        sensor_mm: the scanning rollers' averaging length, mm of fed sliver.
    """

    intensity: float = 1.0
    action_offset_mm: float = 0.0
    sensor_mm: float = 20.0

    def __post_init__(self) -> None:
        if not (0 <= self.intensity <= 2 and abs(self.action_offset_mm) <= 5000
                and 0 < self.sensor_mm <= 1000):  # fmt: skip
            raise ConfigError(f"autoleveller {self}", where="--leveller",
                              fix="intensity 0-2, action offset within +-5000 mm, sensor "
                              "0-1000 mm")  # fmt: skip

    def levelled(self, surface: np.ndarray, p_grid: np.ndarray, relative: np.ndarray,
                 transport: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:  # fmt: skip
        """The surface lengths (mm, ``(m, 4)``) with the upstream rollers driven by the
        leveller, for a feed of ``relative`` thickness on ``p_grid`` (fed mm);
        ``transport(surface)`` gives the delivered leading-end position of each ``p_grid``
        point (NaN where not delivered)."""
        step = float(p_grid[1] - p_grid[0])
        width = max(1, int(round(self.sensor_mm / step)))
        measured = np.convolve(relative, np.ones(width) / width, mode="same")
        base = np.diff(surface, axis=0)
        out = surface
        for _ in range(PASSES):
            lead = transport(out)
            ok = np.isfinite(lead)
            # the fed position whose leading ends reach the front nip at each time
            p_front = np.interp(out[:, 0], lead[ok], p_grid[ok])
            thick = np.interp(p_front + self.action_offset_mm, p_grid, measured)
            factor = np.clip(1.0 / np.maximum(1.0 + self.intensity * (thick - 1.0), 1e-9),
                             MIN_FACTOR, MAX_FACTOR)  # fmt: skip
            mid = 0.5 * (factor[1:] + factor[:-1])
            out = surface.copy()
            for k in UPSTREAM:
                out[1:, k] = surface[0, k] + np.cumsum(base[:, k] * mid)
        return np.ascontiguousarray(out)
