"""The typed container for a series of measured roller speeds."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pandas as pd

from drafttwin import ROLLERS


@dataclass(frozen=True, eq=False)
class MeasurementSeries:
    """Roller speeds sampled on a regular time grid.

    Attributes:
        time_s: sample times in seconds from the start, shape ``(n,)``, strictly increasing.
        rpm: roller speeds in rpm, shape ``(n, len(rollers))``, float64; ``NaN`` marks a
            missing sample.
        rollers: roller names, one per column of ``rpm`` (default: front, second, third, back).
        motor_rpm: optional motor speed in rpm, shape ``(n,)``.
        setpoints: optional set-point channels (e.g. ``supply_hz``), each shape ``(n,)``.
        metadata: free-form provenance (source file, seed, plant parameters, ...).
    """

    time_s: np.ndarray
    rpm: np.ndarray
    rollers: tuple[str, ...] = ROLLERS
    motor_rpm: np.ndarray | None = None
    setpoints: dict[str, np.ndarray] = field(default_factory=dict)
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        time_s = np.asarray(self.time_s, dtype=np.float64)
        rpm = np.asarray(self.rpm, dtype=np.float64)
        if rpm.ndim == 1:
            rpm = rpm[:, None]
        if time_s.ndim != 1 or rpm.shape[0] != time_s.shape[0]:
            raise ValueError(
                f"time_s has shape {time_s.shape} but rpm has shape {rpm.shape}; "
                "they need the same number of rows"
            )
        if rpm.shape[1] != len(self.rollers):
            raise ValueError(f"rpm has {rpm.shape[1]} columns for rollers {self.rollers}")
        object.__setattr__(self, "time_s", time_s)
        object.__setattr__(self, "rpm", rpm)
        object.__setattr__(self, "rollers", tuple(self.rollers))
        if self.motor_rpm is not None:
            object.__setattr__(self, "motor_rpm", np.asarray(self.motor_rpm, dtype=np.float64))

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def sample_rate_hz(self) -> float:
        """Sample rate in Hz, from the median time step."""
        if len(self) < 2:
            return float("nan")
        return float(1.0 / np.median(np.diff(self.time_s)))

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0]) if len(self) else 0.0

    def column(self, roller: str) -> np.ndarray:
        """Speeds of one roller in rpm."""
        return self.rpm[:, self.rollers.index(roller)]

    def slice(self, start: int, stop: int | None = None) -> MeasurementSeries:
        """Rows ``start:stop`` as a new series (sample-index based, like Python slicing)."""
        sl = slice(start, stop)
        return replace(
            self,
            time_s=self.time_s[sl],
            rpm=self.rpm[sl],
            motor_rpm=None if self.motor_rpm is None else self.motor_rpm[sl],
            setpoints={k: v[sl] for k, v in self.setpoints.items()},
        )

    def with_rpm(self, rpm: np.ndarray) -> MeasurementSeries:
        """The same series with replaced roller speeds (e.g. after preprocessing)."""
        return replace(self, rpm=rpm)

    def to_frame(self) -> pd.DataFrame:
        """A DataFrame with ``time`` (s), one rpm column per roller, then motor and set-points."""
        data: dict[str, np.ndarray] = {"time": self.time_s}
        for j, name in enumerate(self.rollers):
            data[name] = self.rpm[:, j]
        if self.motor_rpm is not None:
            data["motor"] = self.motor_rpm
        data.update(self.setpoints)
        return pd.DataFrame(data)
