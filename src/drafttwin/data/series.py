"""The typed container for measured (or simulated) series: named channels, units, inputs and
records."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pandas as pd

from drafttwin._constants import ROLLERS

RPM = "rpm"
"""The unit of the FA320A roller speeds (the default output channels)."""


@dataclass(frozen=True, eq=False)
class MeasurementSeries:
    """Output channels (and optional exogenous inputs) sampled on a regular time grid.

    Attributes:
        time_s: sample times in seconds, shape ``(n,)``, strictly increasing inside each record
            (a file's numeric times are kept as they are, so a simulation and a measurement
            share one time axis; timestamps count from the file's first one; the first time
            is also in ``metadata['time_offset_s']`` or ``metadata['records'][k]``).
        values: output values, shape ``(n, len(channels))``, float64, in each channel's unit;
            ``NaN`` marks a missing sample.
        channels: output channel names, one per column of ``values`` (default: the four
            FA320A bottom rollers front, second, third, back, in rpm).
        units: unit per channel or input name (e.g. ``{"y": "m", "u": "V"}``); output channels
            without an entry are in rpm when they are the four rollers, else unitless (``""``).
        inputs: exogenous input channels known in advance (set-points such as the VFD supply
            frequency ``supply_hz``, a drive voltage), each shape ``(n,)``.
        motor_rpm: optional measured motor speed in rpm, shape ``(n,)``.
        truth: the true output values, shape like ``values``, when they are known (data from
            the plant emulator); ``None`` otherwise. Never a model input: it gives the noise
            floor and the error against the true value in evaluations.
        record_starts: first row of each record (separate experiments concatenated row-wise);
            ``(0,)`` for one record. No model window crosses a record boundary.
        metadata: free-form provenance (source file, seed, plant parameters, ...).
    """

    time_s: np.ndarray
    values: np.ndarray
    channels: tuple[str, ...] = ROLLERS
    units: dict[str, str] = field(default_factory=dict)
    inputs: dict[str, np.ndarray] = field(default_factory=dict)
    motor_rpm: np.ndarray | None = None
    truth: np.ndarray | None = None
    record_starts: tuple[int, ...] = (0,)
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        time_s = np.asarray(self.time_s, dtype=np.float64)
        values = np.asarray(self.values, dtype=np.float64)
        if values.ndim == 1:
            values = values[:, None]
        if time_s.ndim != 1 or values.shape[0] != time_s.shape[0]:
            raise ValueError(
                f"time_s has shape {time_s.shape} but values has shape {values.shape}; "
                "they need the same number of rows"
            )
        channels = tuple(self.channels)
        if values.shape[1] != len(channels):
            raise ValueError(f"values has {values.shape[1]} columns for channels {channels}")
        if len(set(channels)) != len(channels):
            raise ValueError(f"channel names must be distinct, got {channels}")
        inputs = {str(k): np.asarray(v, dtype=np.float64) for k, v in self.inputs.items()}
        for name, col in inputs.items():
            if col.shape != time_s.shape:
                raise ValueError(f"input {name!r} has shape {col.shape}, not {time_s.shape}")
        starts = tuple(int(s) for s in self.record_starts) or (0,)
        n = time_s.shape[0]
        if starts[0] != 0 or any(b <= a for a, b in zip(starts, starts[1:], strict=False)):
            raise ValueError(f"record_starts {starts} must start at 0 and increase")
        if n and starts[-1] >= n:
            raise ValueError(f"record_starts {starts} point past the {n} rows")
        object.__setattr__(self, "time_s", time_s)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "channels", channels)
        object.__setattr__(self, "inputs", inputs)
        object.__setattr__(self, "units", {str(k): str(v) for k, v in self.units.items()})
        object.__setattr__(self, "record_starts", starts)
        if self.motor_rpm is not None:
            object.__setattr__(self, "motor_rpm", np.asarray(self.motor_rpm, dtype=np.float64))
        if self.truth is not None:
            truth = np.asarray(self.truth, dtype=np.float64)
            truth = truth[:, None] if truth.ndim == 1 else truth
            if truth.shape != values.shape:
                raise ValueError(f"truth has shape {truth.shape}, values {values.shape}")
            object.__setattr__(self, "truth", truth)

    # ----- shape and time -------------------------------------------------------------------
    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def sample_rate_hz(self) -> float:
        """Sample rate in Hz, from the median time step inside the records."""
        steps = np.concatenate([np.diff(self.time_s[a:b]) for a, b in self.record_bounds()])
        if steps.size == 0:
            return float("nan")
        return float(1.0 / np.median(steps))

    @property
    def time_column(self) -> str:
        """The name predictions of this series give their time column: the data file's own
        (``t`` stays ``t``) where its values are that file's seconds, else ``time``."""
        name = self.metadata.get("time_column")
        return name if isinstance(name, str) and name and name not in self.channels else "time"

    @property
    def duration_s(self) -> float:
        """Summed duration of the records in seconds."""
        return float(sum(self.time_s[b - 1] - self.time_s[a] for a, b in self.record_bounds()))

    # ----- channels and units ---------------------------------------------------------------
    def unit(self, name: str) -> str:
        """The unit of an output channel or input (``rpm`` for the four rollers by default)."""
        if name in self.units:
            return self.units[name]
        if name in ROLLERS and name in self.channels:
            return RPM
        if name == "supply_hz":
            return "Hz"
        return ""

    def column(self, name: str) -> np.ndarray:
        """Values of one output channel (or, failing that, of one input)."""
        if name in self.channels:
            return self.values[:, self.channels.index(name)]
        if name in self.inputs:
            return self.inputs[name]
        raise KeyError(f"no channel or input {name!r} (channels: {', '.join(self.channels)})")

    # ----- records --------------------------------------------------------------------------
    @property
    def n_records(self) -> int:
        return len(self.record_starts)

    def record_bounds(self) -> list[tuple[int, int]]:
        """``[(start, stop), ...]`` rows of each record."""
        ends = (*self.record_starts[1:], len(self))
        return [(a, b) for a, b in zip(self.record_starts, ends, strict=True) if b > a]

    def record_ids(self) -> np.ndarray:
        """Record index of every row, shape ``(n,)``."""
        out = np.zeros(len(self), dtype=np.int64)
        for k, (a, b) in enumerate(self.record_bounds()):
            out[a:b] = k
        return out

    def records(self) -> Iterator[MeasurementSeries]:
        """Each record as a series of its own."""
        metas = self.metadata.get("records")
        for k, (a, b) in enumerate(self.record_bounds()):
            part = self.slice(a, b)
            if isinstance(metas, list) and k < len(metas):
                part = replace(part, metadata={**self.metadata, **metas[k], "records": None})
            yield part

    @classmethod
    def concat(cls, parts: Sequence[MeasurementSeries]) -> MeasurementSeries:
        """Records side by side as one series (same channels, units and inputs in each)."""
        if not parts:
            raise ValueError("concat needs at least one series")
        first = parts[0]
        for p in parts[1:]:
            if p.channels != first.channels or sorted(p.inputs) != sorted(first.inputs):
                raise ValueError(
                    f"records differ in channels: {list(first.channels)} + "
                    f"{sorted(first.inputs)} vs {list(p.channels)} + {sorted(p.inputs)}"
                )
        starts: list[int] = []
        offset = 0
        for p in parts:
            starts += [offset + s for s in p.record_starts]
            offset += len(p)
        motor = None
        if all(p.motor_rpm is not None for p in parts):
            motor = np.concatenate([p.motor_rpm for p in parts if p.motor_rpm is not None])
        truth = None
        if any(p.truth is not None for p in parts):  # unknown parts: NaN
            truth = np.vstack([np.full(p.values.shape, np.nan) if p.truth is None else p.truth
                               for p in parts])  # fmt: skip
        return cls(
            time_s=np.concatenate([p.time_s for p in parts]),
            values=np.vstack([p.values for p in parts]),
            channels=first.channels,
            units={k: v for p in parts for k, v in p.units.items()},
            inputs={k: np.concatenate([p.inputs[k] for p in parts]) for k in first.inputs},
            motor_rpm=motor,
            truth=truth,
            record_starts=tuple(starts),
            metadata={**first.metadata, "records": [p.metadata for p in parts]},
        )

    # ----- derived series -------------------------------------------------------------------
    def slice(self, start: int, stop: int | None = None) -> MeasurementSeries:
        """Rows ``start:stop`` as a new series (sample-index based, like Python slicing); the
        record boundaries inside the slice are kept."""
        a, b, _ = slice(start, stop).indices(len(self))
        b = max(a, b)
        starts = [0] + [s - a for s in self.record_starts if a < s < b]
        metadata = self.metadata
        metas = metadata.get("records")
        if isinstance(metas, list) and len(metas) == self.n_records:
            first = sum(1 for s in self.record_starts if s <= a) - 1  # record holding row a
            metadata = {**metadata, "records": metas[first : first + len(starts)]}
        return replace(
            self,
            metadata=metadata,
            time_s=self.time_s[a:b],
            values=self.values[a:b],
            inputs={k: v[a:b] for k, v in self.inputs.items()},
            motor_rpm=None if self.motor_rpm is None else self.motor_rpm[a:b],
            truth=None if self.truth is None else self.truth[a:b],
            record_starts=tuple(starts),
        )

    def with_values(self, values: np.ndarray) -> MeasurementSeries:
        """The same series with replaced output values (e.g. after preprocessing)."""
        return replace(self, values=values)

    def to_frame(self) -> pd.DataFrame:
        """A DataFrame with ``time`` (s), one column per output channel, then motor and inputs
        (and ``record`` when there are several records)."""
        data: dict[str, np.ndarray] = {"time": self.time_s}
        for j, name in enumerate(self.channels):
            data[name] = self.values[:, j]
        if self.motor_rpm is not None:
            data["motor"] = self.motor_rpm
        data.update(self.inputs)
        if self.n_records > 1:
            data["record"] = self.record_ids()
        return pd.DataFrame(data)
