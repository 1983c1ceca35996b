"""The rollers' surface speeds that drive the drafting simulator.

:class:`SurfaceSpeeds` holds each bottom roller's cumulative surface length on a uniform time
grid: integrating the speed keeps every interval's exact travel, which is what decides where
a fibre lands. Sources:

* :meth:`SurfaceSpeeds.from_rpm`: interval-mean roller speeds (rpm), as encoders report them
  and as every model predicts them (measured files, the plant's true speeds, a hybrid's
  prediction, the physics);
* :meth:`SurfaceSpeeds.from_lengths`: cumulative surface lengths at a fine rate (the plant's
  true surfaces, with an eccentric roller's radius);
* :meth:`SurfaceSpeeds.with_detail`: content above a coarse record's Nyquist frequency taken
  from a fine-rate simulation of the physics (its mesh and once-per-revolution lines), never
  from aliased samples: the coarse record keeps every interval's travel, the detail adds only
  how the travel is spread within each interval.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drafttwin.data.gaps import interpolate_missing
from drafttwin.errors import DataError

ROLLER_ORDER = ("front", "second", "third", "back")


@dataclass(frozen=True)
class SurfaceSpeeds:
    """Cumulative surface length of front, second, third and back roller.

    Attributes:
        time_s: uniform time grid, s, shape ``(m,)``.
        length_m: cumulative surface length, m, shape ``(m, 4)``, non-decreasing.
        source: where the speeds came from (for reports).
    """

    time_s: np.ndarray
    length_m: np.ndarray
    source: str = ""

    def __post_init__(self) -> None:
        t, s = np.asarray(self.time_s, np.float64), np.asarray(self.length_m, np.float64)
        if t.ndim != 1 or s.shape != (t.size, 4) or t.size < 3:
            raise DataError("surface lengths must be (m, 4) on a time grid of m >= 3 points",
                            source=self.source or None)  # fmt: skip
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(s))):
            raise DataError("surface lengths or times are not finite", source=self.source or None)
        dt = np.diff(t)
        if not (dt.min() > 0 and np.allclose(dt, dt.mean(), rtol=1e-6, atol=1e-12)):
            raise DataError("the time grid of the roller speeds is not uniform",
                            source=self.source or None,
                            fix="give speeds on a uniform time grid (gaps as empty cells)")  # fmt: skip
        object.__setattr__(self, "time_s", t)
        object.__setattr__(self, "length_m", np.maximum.accumulate(s, axis=0))

    @classmethod
    def from_rpm(cls, time_s: np.ndarray, rpm: np.ndarray, diameters_mm: dict[str, float],
                 source: str = "") -> SurfaceSpeeds:  # fmt: skip
        """From interval-mean speeds (rpm, ``(n, 4)``, front..back) ending at ``time_s``.
        Missing samples (NaN) are filled linearly between their neighbours; negative speeds
        (a sensor's sign) count as magnitudes."""
        t = np.asarray(time_s, np.float64)
        x = np.abs(np.asarray(rpm, np.float64))
        if x.shape != (t.size, 4) or t.size < 2:
            raise DataError("roller speeds must be (n, 4) on n >= 2 time stamps",
                            source=source or None)  # fmt: skip
        step = float(np.median(np.diff(t)))
        x = np.column_stack([_fill(x[:, k], source, r) for k, r in enumerate(ROLLER_ORDER)])
        d = np.array([diameters_mm[r] for r in ROLLER_ORDER]) * 1e-3
        travel = x / 60.0 * math.pi * d * step
        length = np.vstack([np.zeros(4), np.cumsum(travel, axis=0)])
        return cls(np.concatenate([[t[0] - step], t]), length, source)

    @classmethod
    def from_lengths(cls, time_s: np.ndarray, length_m: np.ndarray,
                     source: str = "") -> SurfaceSpeeds:  # fmt: skip
        return cls(time_s, np.asarray(length_m, np.float64) - length_m[0], source)

    @property
    def step_s(self) -> float:
        return float(self.time_s[1] - self.time_s[0])

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0])

    @property
    def delivered_length_m(self) -> float:
        """Sliver delivered by the front roller over the record, m."""
        return float(self.length_m[-1, 0] - self.length_m[0, 0])

    def mean_speed_m_min(self) -> dict[str, float]:
        """Each roller's mean surface speed over the record, m/min."""
        v = (self.length_m[-1] - self.length_m[0]) / self.duration_s * 60.0
        return {r: float(v[k]) for k, r in enumerate(ROLLER_ORDER)}

    def drafts(self) -> dict[str, float]:
        """Mean zone drafts over the record (ratios of surface travel)."""
        v = self.mean_speed_m_min()
        return {"total": v["front"] / v["back"], "main": v["front"] / v["second"],
                "middle": v["second"] / v["third"], "break": v["third"] / v["back"]}  # fmt: skip

    def with_detail(self, detail: SurfaceSpeeds) -> SurfaceSpeeds:
        """These (coarse) speeds on ``detail``'s finer grid, with ``detail``'s content within
        each coarse interval: ``coarse(t) + detail(t) - detail_interpolated(t)``, where the
        interpolations are linear between the coarse grid's points. At the coarse points the
        result equals these speeds exactly."""
        t = detail.time_s
        inside = (t >= self.time_s[0]) & (t <= self.time_s[-1])
        t = t[inside]
        out = np.empty((t.size, 4))
        for k in range(4):
            base = np.interp(t, self.time_s, self.length_m[:, k])
            fine = detail.length_m[inside, k]
            coarse_pts = np.interp(self.time_s, detail.time_s, detail.length_m[:, k])
            out[:, k] = base + fine - np.interp(t, self.time_s, coarse_pts)
        return SurfaceSpeeds(t, out, f"{self.source} + detail from {detail.source}")


def _fill(x: np.ndarray, source: str, name: str) -> np.ndarray:
    """The roller's speeds with their gaps filled (paper eq. 12, the data layer's filling)."""
    if np.isfinite(x).sum() < 2:
        raise DataError(f"roller '{name}' has fewer than two valid speeds", source=source or None,
                        fix="give a record with the roller's speed")  # fmt: skip
    return interpolate_missing(x)[0]
