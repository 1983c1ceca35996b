"""A sliver record: linear density on a delivered-length grid, and its files.

:class:`Sliver` is the one container of the sliver layer (as ``MeasurementSeries`` is for
speeds): the drafting simulator returns it, the plant's delivery sensor writes it, and the
evenness, the spectrogram and the diagnosis read it. Its files are CSV or Parquet with the
columns ``delivered_length_m`` (the grid's bin centres, m) and ``linear_density_ktex``
(g/m), optionally ``time`` (s, when that piece passed the front nip).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from drafttwin._io import atomic_path
from drafttwin.errors import DataError
from drafttwin.sliver.staple import StapleDiagram

LENGTH_COLUMN = "delivered_length_m"
DENSITY_COLUMN = "linear_density_ktex"


@dataclass(frozen=True)
class Sliver:
    """Linear density of a sliver along its delivered length.

    Attributes:
        linear_density_ktex: mean linear density of each grid bin, ktex, shape ``(n,)``.
        step_m: grid step, m (bins are ``[start_m + i step, start_m + (i+1) step]``).
        start_m: delivered length at the grid's start, m.
        time_s: when each bin's centre passed the front nip, s (None if unknown).
        staple: the fibres, where known (for Martindale's limit and the ideal curve).
        fibre_scale: fibres lumped into one by the simulator (1: every fibre drawn).
        info: provenance (seed, speeds, drafts, fibres drawn, ...).
        fibres: drafted fibres kept for a later passage, ``(r, 3)``: leading end (mm on this
            sliver's grid), length (mm), linear density (tex); None if not kept.
        fed: the feed's relative rate as drafted: ``(start_mm, step_mm, values)`` on the
            fed-length grid (the back roller's surface length, 0 at the record's start), for
            an infeed sensor; None if unknown.
    """

    linear_density_ktex: np.ndarray
    step_m: float
    start_m: float = 0.0
    time_s: np.ndarray | None = None
    staple: StapleDiagram | None = None
    fibre_scale: float = 1.0
    info: dict[str, Any] = field(default_factory=dict)
    fibres: np.ndarray | None = None
    fed: tuple[float, float, np.ndarray] | None = None

    @property
    def delivered_length_m(self) -> np.ndarray:
        """Bin centres, m."""
        n = self.linear_density_ktex.size
        return self.start_m + (np.arange(n) + 0.5) * self.step_m

    @property
    def length_m(self) -> float:
        return float(self.linear_density_ktex.size * self.step_m)

    @property
    def count_ktex(self) -> float:
        return float(np.mean(self.linear_density_ktex))

    def to_frame(self) -> pd.DataFrame:
        cols: dict[str, np.ndarray] = {LENGTH_COLUMN: self.delivered_length_m}
        if self.time_s is not None:
            cols["time"] = self.time_s
        cols[DENSITY_COLUMN] = self.linear_density_ktex
        return pd.DataFrame(cols)

    def write(self, path: str | Path) -> Path:
        """Write CSV or Parquet atomically (temporary file, then rename)."""
        path = Path(path)
        with atomic_path(path) as tmp:
            frame_to_file(self.to_frame(), tmp, path.suffix)
        return path


def frame_to_file(frame: pd.DataFrame, tmp: Path, suffix: str) -> None:
    """A sliver frame to ``tmp`` as Parquet or CSV by the final file's ``suffix``."""
    if suffix.lower() == ".parquet":
        frame.to_parquet(tmp, index=False)
    else:
        frame.to_csv(tmp, index=False, float_format="%.10g")


def read_sliver(path: str | Path, column: str = DENSITY_COLUMN, option: str = "--data",
                staple: StapleDiagram | None = None) -> Sliver:  # fmt: skip
    """Read a sliver record (mass per length on a delivered-length axis) and check it: the
    length column increasing and evenly spaced (within 1 %), the density finite and > 0.
    ``column`` names the density column (any unit proportional to mass per length)."""
    path = Path(path)
    if path.suffix.lower() not in (".csv", ".parquet"):
        raise DataError("a sliver record must be .csv or .parquet", source=path, where=option)
    frame = pd.read_parquet(path) if path.suffix.lower() == ".parquet" else pd.read_csv(path)
    for col in (LENGTH_COLUMN, column):
        if col not in frame.columns:
            raise DataError(f"no column '{col}' (columns: {', '.join(map(str, frame.columns))})",
                            source=path, where=option,
                            fix=f"give {LENGTH_COLUMN} (m) and the density column "
                            "(--column)")  # fmt: skip
    s = pd.to_numeric(frame[LENGTH_COLUMN], errors="coerce").to_numpy(np.float64)
    rho = pd.to_numeric(frame[column], errors="coerce").to_numpy(np.float64)
    bad = np.flatnonzero(~np.isfinite(s) | ~np.isfinite(rho) | (rho <= 0))
    if bad.size:
        raise DataError(f"row {int(bad[0]) + 2}: length or density not a finite number > 0",
                        source=path, where=f"{option}, column {column}",
                        fix="a sliver record has no gaps; cut it at the gap")  # fmt: skip
    if s.size < 100:
        raise DataError(f"{s.size} rows: too short for evenness", source=path, where=option,
                        fix="give at least 100 points")  # fmt: skip
    step = np.diff(s)
    h = float(np.median(step))
    if not (h > 0 and np.all(np.abs(step - h) <= 0.01 * h)):
        raise DataError(f"{LENGTH_COLUMN} is not increasing in even steps", source=path,
                        where=option, fix="resample the record on an even length grid")  # fmt: skip
    time = frame["time"].to_numpy(np.float64) if "time" in frame.columns else None
    return Sliver(rho, h, start_m=float(s[0] - h / 2), time_s=time, staple=staple,
                  info={"file": path.name, "column": column})  # fmt: skip


@dataclass(frozen=True)
class SliverBeside:
    """A sliver channel recorded beside a speed record (named in its ``.json`` sidecar)."""

    sliver: Path
    speeds: Path
    sensor_mm: float


def sliver_beside(path: str | Path) -> SliverBeside | None:
    """The sliver channel of a speed record ``x.csv`` (its sidecar ``x.json`` names
    ``x.sliver.csv``), or of that sliver file itself; None if there is none. The sidecar is
    checked before it is trusted: a file it names must exist beside it."""
    import json

    path = Path(path)
    stem = path.stem[: -len(".sliver")] if path.stem.endswith(".sliver") else path.stem
    speeds = path.with_name(stem + path.suffix)
    sidecar = path.with_name(stem + ".json")
    try:
        info = json.loads(sidecar.read_text(encoding="utf-8"))
        name = info["files"]["sliver"]
        sensor = float(info["sliver"]["delivery_sensor"]["averaging_mm"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    sliver = path.with_name(str(name))
    if Path(str(name)).name != str(name) or not sliver.is_file() or not speeds.is_file():
        return None
    return SliverBeside(sliver, speeds, sensor)
