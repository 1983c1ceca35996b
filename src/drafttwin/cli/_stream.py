"""Writing a table piece by piece, and summarising it as it passes.

A long ``simulate`` produces its rows in pieces (:func:`drafttwin.mechanics.simulate_chunks`);
:class:`FrameStream` appends each to a CSV file or a Parquet row group in a temporary file
beside the target and renames it when the last piece is in (nothing half-written on
failure), and :class:`RunningStats` keeps what the summary table needs. Memory holds one
piece, whatever the duration. The CSV text equals ``DataFrame.to_csv`` of the whole table.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from drafttwin._io import atomic_path
from drafttwin.cli._common import CSV_FLOAT_FORMAT, check_output_suffix, csv_ready


class FrameStream:
    """Append DataFrame pieces (same columns) to a CSV or Parquet file being written."""

    def __init__(self, tmp: Path, parquet: bool) -> None:
        self._tmp, self._parquet = tmp, parquet
        self._writer: Any = None  # a pyarrow ParquetWriter, opened with the first piece
        self._started = False
        self.rows = 0

    def write(self, frame: pd.DataFrame) -> None:
        if self._parquet:
            import pyarrow as pa
            import pyarrow.parquet as pq

            table = pa.Table.from_pandas(frame, preserve_index=False)
            if self._writer is None:
                self._writer = pq.ParquetWriter(self._tmp, table.schema)
            self._writer.write_table(table)
        else:
            csv_ready(frame).to_csv(self._tmp, mode="a" if self._started else "w",
                                    header=not self._started, index=False,
                                    float_format=CSV_FLOAT_FORMAT)  # fmt: skip
        self._started = True
        self.rows += len(frame)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None


@contextlib.contextmanager
def frame_stream(path: Path) -> Iterator[FrameStream]:
    """A :class:`FrameStream` into a temporary file renamed onto ``path`` (``.csv`` or
    ``.parquet``) when the block ends without an error; removed otherwise."""
    check_output_suffix(path)
    with atomic_path(path) as tmp:
        stream = FrameStream(tmp, parquet=path.suffix.lower() == ".parquet")
        try:
            yield stream
        finally:
            stream.close()


@dataclass
class _Moments:
    n: int = 0
    mean: float = 0.0
    m2: float = 0.0  # sum of squared deviations from the mean
    low: float = math.inf
    high: float = -math.inf


@dataclass
class RunningStats:
    """Mean, standard deviation and range of each column over all pieces seen (Chan et al.'s
    pairwise update: no cancellation for a large mean with a small spread)."""

    columns: dict[str, _Moments] = field(default_factory=dict)

    def add(self, frame: pd.DataFrame) -> None:
        for name in frame.columns:
            if name in ("time", "record"):
                continue
            x = frame[name].to_numpy(dtype=np.float64)
            if x.size == 0:
                continue
            acc = self.columns.setdefault(name, _Moments())
            n_b, mean_b = x.size, float(np.mean(x))
            m2_b = float(np.sum((x - mean_b) ** 2))
            n = acc.n + n_b
            delta = mean_b - acc.mean
            acc.mean += delta * n_b / n
            acc.m2 += m2_b + delta * delta * acc.n * n_b / n
            acc.n = n
            acc.low, acc.high = min(acc.low, float(np.min(x))), max(acc.high, float(np.max(x)))

    def rows(self) -> Iterator[tuple[str, float, float, float]]:
        """``(column, mean, std, peak-to-peak)`` per column (population std, as np.std)."""
        for name, acc in self.columns.items():
            yield name, acc.mean, math.sqrt(acc.m2 / acc.n), acc.high - acc.low


__all__ = ["FrameStream", "RunningStats", "frame_stream"]
