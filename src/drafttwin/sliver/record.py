"""A sliver record: linear density on a delivered-length grid, and its files.

:class:`Sliver` is the one container of the sliver layer (as ``MeasurementSeries`` is for
speeds): the drafting simulator returns it, the plant's delivery sensor writes it, and the
evenness, the spectrogram and the diagnosis read it. Its files are CSV or Parquet with the
columns ``delivered_length_m`` (the grid's bin centres, m) and ``linear_density_ktex``
(g/m), optionally ``time`` (s, when that piece passed the front nip).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from drafttwin._io import atomic_path
from drafttwin.errors import DataError
from drafttwin.sliver.staple import StapleDiagram

if TYPE_CHECKING:
    from drafttwin.sliver.leveller import Levelling

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
        levelling: what an autoleveller did (its readings, setting, the feeding roller's
            levelled travel); None without one.
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
    levelling: Levelling | None = None

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


LENGTH_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
"""Units a length column may carry (in its name: ``length_cm``, ``length [mm]``), in m."""
RECOGNISED_LENGTHS = ("delivered_length", "length", "position", "distance", "sliver_length")
"""Names of a length column recognised without ``--length-column`` (with a unit suffix)."""
NOT_DENSITY = ("time", "time_s", "infeed_ktex", "fed_length_m", "record")
"""Columns never taken as the density when the record names none."""


def read_sliver(path: str | Path, column: str | None = None, option: str = "--data",
                staple: StapleDiagram | None = None, length_column: str | None = None,
                length_unit: str | None = None) -> Sliver:  # fmt: skip
    """Read a sliver record (mass per length on a delivered-length axis) and check it: the
    length column increasing and evenly spaced (within 1 %), the density finite and > 0.

    The file goes through the data layer's checks (:func:`drafttwin.data.io.read_table`:
    binary or damaged files are refused with one line). ``length_column`` names the length
    column; without it one of ``delivered_length_m``, ``length_m``, ``position_m``, ... (also
    ``_cm``, ``_mm``) is taken. Its unit comes from its name (``_m``, ``_cm``, ``_mm``, or
    ``[cm]``) or ``length_unit``. ``column`` names the density column (any unit proportional
    to mass per length); without it ``linear_density_ktex``, else the one numeric column
    left. ``option`` is the CLI option named in errors."""
    from drafttwin.data.io import read_table

    path = Path(path)
    frame = read_table(path, option=option)
    frame.columns = [str(c) for c in frame.columns]
    length_col, scale = find_length_column(frame, length_column, length_unit, path, option)
    rho_col = _density_column(frame, column, length_col, path, option)
    s = pd.to_numeric(frame[length_col], errors="coerce").to_numpy(np.float64) * scale
    rho = pd.to_numeric(frame[rho_col], errors="coerce").to_numpy(np.float64)
    bad = np.flatnonzero(~np.isfinite(s) | ~np.isfinite(rho) | (rho <= 0))
    if bad.size:
        row = int(bad[0])
        what, fix = _bad_value(frame[length_col].iloc[row], frame[rho_col].iloc[row], row)
        raise DataError(f"row {row + 1} (line {row + 2}): {what}", source=path,
                        where=f"{option}, column {rho_col}", fix=fix)  # fmt: skip
    if s.size < 100:
        raise DataError(f"{s.size} rows: too short for evenness", source=path, where=option,
                        fix="give at least 100 points")  # fmt: skip
    rho = _in_ktex(rho, rho_col, path, option)
    step = np.diff(s)
    h = float(np.median(step))
    if not (h > 0 and np.all(np.abs(step - h) <= 0.01 * h)):
        raise DataError(f"{length_col} is not increasing in even steps", source=path,
                        where=f"{option}, column {length_col}",
                        fix="resample the record on an even length grid")  # fmt: skip
    time = None
    if "time" in frame.columns:
        t = pd.to_numeric(frame["time"], errors="coerce").to_numpy(np.float64)
        time = t if bool(np.all(np.isfinite(t))) else None
    return Sliver(rho, h, start_m=float(s[0] - h / 2), time_s=time, staple=staple,
                  info={"file": path.name, "column": rho_col,
                        "length_column": length_col})  # fmt: skip


DENSITY_UNITS = {"ktex": 1.0, "dtex": 1e-4, "tex": 1e-3, "mg/m": 1e-3, "g/m": 1.0,
                 "mg_per_m": 1e-3, "g_per_m": 1.0}  # fmt: skip
"""Units a density column may carry in its name (``linear_density_tex``, ``mass [g/m]``), in
ktex (g/m); longer names first where one ends another (``ktex``, ``dtex`` before ``tex``)."""
COUNT_RANGE_KTEX = (0.001, 100.0)
"""Linear densities a record of fibre strands can have (yarn of 1 tex to the thickest card
sliver, 10 ktex, with room): a tex column read as ktex had given "count 5019 ktex"."""
SPIKE_FACTOR = 50.0
"""A cell this many times the record's median is a broken cell, not a thick place."""


def _in_ktex(rho: np.ndarray, column: str, path: Path, option: str) -> np.ndarray:
    """The density in ktex where its column's name gives a unit (checked for a count a
    strand can have), refused where one cell is a broken one (one 1e300: "CV inf %")."""
    median = float(np.median(rho))
    spikes = np.flatnonzero(rho > SPIKE_FACTOR * median)
    if spikes.size:
        row = int(spikes[0])
        raise DataError(f"row {row + 1} (line {row + 2}): density {rho[row]:.6g} is {rho[row] / median:.3g} times "
                        f"the record's median ({median:.6g}): a broken cell, not a thick place",
                        source=path, where=f"{option}, column {column}",
                        fix="correct or cut that part of the record")  # fmt: skip
    low = column.strip().lower()
    unit = next((u for u in DENSITY_UNITS
                 if any(low.endswith(f) for f in (f"_{u}", f"[{u}]", f"({u})", f" {u}"))), None)  # fmt: skip
    if unit is None:  # any unit proportional to the mass per length: CV and spectra hold
        return rho
    ktex = rho * DENSITY_UNITS[unit]
    count, (lo, hi) = float(np.mean(ktex)), COUNT_RANGE_KTEX
    if not lo <= count <= hi:
        hint = " (in tex, not ktex?)" if unit == "ktex" and count > hi else ""
        raise DataError(f"mean density {count:.6g} ktex is no count a sliver, roving or yarn "
                        f"has ({lo:g} to {hi:g} ktex){hint}", source=path,
                        where=f"{option}, column {column}",
                        fix="name the column by its unit (linear_density_tex, "
                        "linear_density_ktex) or name another with --column")  # fmt: skip
    return ktex


def _unit_of(name: str) -> tuple[str, str] | None:
    """The length unit a column name carries (``x_cm``, ``x [cm]``, ``x (cm)``) and the name
    without it."""
    low = name.strip().lower()
    for unit in LENGTH_UNITS:
        for suffix in (f"_{unit}", f"[{unit}]", f"({unit})", f" {unit}"):
            if low.endswith(suffix):
                return unit, low[: -len(suffix)].strip()
    return None


def _bad_value(length: object, density: object, row: int) -> tuple[str, str]:
    """What is wrong with a row's length or density cell, and the fix, in a tester's terms."""
    cells = [str(c).strip() for c in (length, density)]
    if any("," in c and c.replace(",", "").replace("-", "").isdigit() for c in cells):
        return (
            f"'{cells[0]}', '{cells[1]}': a decimal comma",
            "export with a decimal point (or convert the file)",
        )
    numbers = pd.to_numeric(pd.Series(cells), errors="coerce")
    if row == 0 and numbers.isna().all():
        return (
            f"'{cells[0]}', '{cells[1]}' is not a number: a units row below the header?",
            "delete that row (units go in the column name, e.g. length_m)",
        )
    if numbers.isna().any():
        return (
            f"'{cells[0]}', '{cells[1]}': a missing or non-numeric value",
            "a sliver record has no gaps; cut it at the gap",
        )
    if float(numbers.iloc[1]) <= 0:
        return (
            f"density {cells[1]} is not above 0",
            "give the mass per length (a tester's deviation in % is no density; "
            "--column names the density column)",
        )
    return (
        f"'{cells[0]}', '{cells[1]}': length or density not a finite number",
        "a sliver record has no gaps; cut it at the gap",
    )


def find_length_column(frame: pd.DataFrame, named: str | None, unit: str | None, path: Path,
                       option: str, naming: bool = True) -> tuple[str, float]:  # fmt: skip
    """The length column of a sliver table (named, else recognised) and its scale to m;
    ``naming``: the command has --length-column (its fix says so)."""
    columns = ", ".join(map(str, frame.columns))
    if unit is not None and unit not in LENGTH_UNITS:
        raise DataError(f"length unit '{unit}'", where="--length-unit", fix="m, cm or mm")
    if named is not None:
        found = _match(frame, named)
        if found is None:
            raise DataError(f"no column '{named}' (columns: {columns})", source=path,
                            where=f"{option}, --length-column",
                            fix="name the delivered-length column of the file")  # fmt: skip
    else:
        candidates = sorted((c for c in frame.columns if _is_length_name(c)), key=_priority)
        if not candidates:
            raise DataError(f"no length column (columns: {columns})", source=path, where=option,
                            fix="name it with --length-column (e.g. --length-column length_m), "
                            "or call it delivered_length_m" if naming else "call the delivered "
                            "length column delivered_length_m (m)")  # fmt: skip
        found = candidates[0]
    carried = _unit_of(found)
    if unit is not None and carried and carried[0] != unit:
        raise DataError(f"column '{found}' says its lengths are in {carried[0]}, but "
                        f"--length-unit says {unit}", source=path, where="--length-unit",
                        fix="leave --length-unit out (the column's name says the unit)")  # fmt: skip
    unit = unit or (carried[0] if carried else None)
    if unit is None:
        raise DataError(f"column '{found}' does not say its unit", source=path,
                        where=f"{option}, --length-column",
                        fix="give --length-unit m|cm|mm (or name it e.g. length_m)")  # fmt: skip
    return found, LENGTH_UNITS[unit]


def _priority(name: str) -> int:
    carried = _unit_of(name)
    return RECOGNISED_LENGTHS.index(carried[1]) if carried else len(RECOGNISED_LENGTHS)


def _is_length_name(name: str) -> bool:
    carried = _unit_of(name)
    return carried is not None and carried[1] in RECOGNISED_LENGTHS


def _match(frame: pd.DataFrame, name: str) -> str | None:
    """The frame's column called ``name`` (exactly, else ignoring case and spaces)."""
    if name in frame.columns:
        return name
    low = name.strip().lower()
    return next((c for c in frame.columns if c.strip().lower() == low), None)


def _density_column(frame: pd.DataFrame, named: str | None, length_col: str, path: Path,
                    option: str) -> str:  # fmt: skip
    """The density column: the one named, ``linear_density_ktex``, or the one numeric
    column left beside length and time."""
    columns = ", ".join(map(str, frame.columns))
    if named is not None:
        found = _match(frame, named)
        if found is None:
            raise DataError(f"no column '{named}' (columns: {columns})", source=path,
                            where=f"{option}, --column",
                            fix="name the density column with --column")  # fmt: skip
        return found
    found = _match(frame, DENSITY_COLUMN)
    if found is not None:
        return found
    left = [c for c in frame.columns if c != length_col and c.strip().lower() not in NOT_DENSITY
            and pd.to_numeric(frame[c], errors="coerce").notna().any()]  # fmt: skip
    if len(left) != 1:
        raise DataError(f"which column is the density? (columns: {columns})", source=path,
                        where=f"{option}, --column",
                        fix="name the density column with --column")  # fmt: skip
    return str(left[0])


@dataclass(frozen=True)
class SliverBeside:
    """A sliver channel recorded beside a speed record (named in its ``.json`` sidecar)."""

    sliver: Path
    speeds: Path
    sensor_mm: float
    sidecar: dict[str, Any] = field(default_factory=dict)
    """The sidecar's ``sliver`` section (settings, fibres, the leveller's)."""

    @property
    def staple(self) -> dict[str, Any] | None:
        """The fibres the record was made of, as the sidecar describes them."""
        described = self.sidecar.get("staple")
        return described if isinstance(described, dict) else None

    @property
    def fibre_scale(self) -> float | None:
        """Fibres the simulator lumped into one, as the sidecar says (None: not said)."""
        value = self.sidecar.get("fibre_scale")
        if not isinstance(value, int | float) or isinstance(value, bool):
            return None
        scale = float(value)
        return scale if math.isfinite(scale) and 1.0 <= scale <= 1e6 else None


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
    section = info["sliver"] if isinstance(info.get("sliver"), dict) else {}
    return SliverBeside(sliver, speeds, sensor, section)
