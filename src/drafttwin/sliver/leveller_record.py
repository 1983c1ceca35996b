"""What a levelling drawframe records, and its leveller's setting: the input of
:func:`drafttwin.sliver.action_point.find_action_point`.

A record's file (``generate --sliver``'s ``.sliver`` file) has one row per delivery reading:
``delivered_length_m`` (or a recognised length column), ``time`` (s),
``linear_density_ktex`` (the delivery sensor), ``infeed_ktex`` (the infeed scanning rollers'
reading held then) and ``fed_length_m`` (the store's length clock: the feeding rollers'
travel). A plant record's sidecar names the leveller's setting (``sliver.leveller``), the
fibres and the delivery sensor; a file without one takes them from options.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from drafttwin.errors import ConfigError, DataError
from drafttwin.sliver.leveller import NOMINAL_DRIVE_S
from drafttwin.sliver.sensor import SliverSensor

COLUMNS = ("time", "linear_density_ktex", "infeed_ktex", "fed_length_m")
"""Columns a leveller record needs beside its length column."""


@dataclass(frozen=True)
class LevellerSetting:
    """A leveller's setting as the machine holds it.

    Attributes:
        action_point_mm: store length from the scanning rollers to the action point, mm of
            fed sliver (what a mill types).
        intensity: fraction of the measured excess corrected (0: no levelling).
        reference_ktex: the count the infeed reading is levelled to, ktex (None: the
            readings' median).
        drive_time_constant_s: the regulating drive's nominal time constant, s.
    """

    action_point_mm: float
    intensity: float
    reference_ktex: float | None = None
    drive_time_constant_s: float = NOMINAL_DRIVE_S


@dataclass(frozen=True)
class LevellerRecord:
    """What a levelling drawframe records, one row per delivery reading.

    Attributes:
        delivered_length_m: the readings' delivered length, m, on an even grid.
        delivery_ktex: the delivery sensor's readings, ktex.
        infeed_ktex: the infeed scanning rollers' reading held at that moment, ktex.
        fed_length_m: the store's length clock (the feeding rollers' travel), m.
        time_s: when each reading was taken, s.
        source: where the readings came from (a file), for messages.
    """

    delivered_length_m: np.ndarray
    delivery_ktex: np.ndarray
    infeed_ktex: np.ndarray
    fed_length_m: np.ndarray
    time_s: np.ndarray
    source: str = ""

    def __post_init__(self) -> None:
        n = self.delivered_length_m.size
        arrays = (self.delivery_ktex, self.infeed_ktex, self.fed_length_m, self.time_s)
        if n < 1000 or any(a.shape != (n,) for a in arrays):
            raise DataError(f"{n} readings: a leveller record needs at least 1000 rows of "
                            "delivered length, delivery, infeed, fed length and time",
                            source=self.source or None,
                            fix="give a record of a few hundred metres")  # fmt: skip

    @property
    def step_m(self) -> float:
        return float(np.median(np.diff(self.delivered_length_m)))

    @property
    def length_m(self) -> float:
        return float(self.delivered_length_m.size * self.step_m)

    def head(self, length_m: float) -> LevellerRecord:
        """The first ``length_m`` metres: the rows before ``start + length_m`` (half a step's
        margin), at least 1000; the same rows from any longer record that begins alike (the
        live twin's window is the command's ``--max-length``)."""
        s = self.delivered_length_m
        n = int(np.searchsorted(s, s[0] + length_m - 0.5 * self.step_m, side="left"))
        n = min(s.size, max(n, 1000))
        return LevellerRecord(self.delivered_length_m[:n], self.delivery_ktex[:n],
                              self.infeed_ktex[:n], self.fed_length_m[:n], self.time_s[:n],
                              self.source)  # fmt: skip


@dataclass(frozen=True)
class LevellerFile:
    """A leveller record read from a file, with what its sidecar says.

    Attributes:
        record: the readings.
        setting: the leveller's setting the sidecar names (None: none there; a record made
            without a leveller has intensity 0 and no action point).
        had_leveller: whether the sidecar says the record was made with a leveller.
        staple: the sidecar's description of the fibres (None: none).
        delivery: the delivery sensor the sidecar names (None: none).
        true_action_point_mm: a plant record's true action point (for checks; the estimator
            never reads it).
    """

    record: LevellerRecord
    setting: LevellerSetting | None
    had_leveller: bool
    staple: dict[str, Any] | None
    delivery: SliverSensor | None
    true_action_point_mm: float | None


def read_leveller_record(path: str | Path, option: str = "--data",
                         machine: str | None = None) -> LevellerFile:  # fmt: skip
    """A leveller record: the sliver file beside a plant record (or that file itself, or any
    file with the columns), read through the data layer's file checks; ``machine``: the rows
    of that machine in a log of several (``plant serve --machines N --sliver --log``)."""
    from drafttwin.data.io import read_table
    from drafttwin.sliver.record import find_length_column, sliver_beside

    path = Path(path)
    beside = sliver_beside(path)
    source = beside.sliver if beside else path
    frame = read_table(source, option=option)
    frame.columns = [str(c) for c in frame.columns]
    frame = _one_machine(frame, machine, source)
    sliver_log = source.with_name(source.stem + ".sliver" + source.suffix)
    if "ts_us" in frame.columns and sliver_log.is_file():  # a plant log's speed file
        raise DataError("a plant log's speed records, not its sliver readings", source=source,
                        where=option, fix=f"give {sliver_log.name}, the log's sliver readings")  # fmt: skip
    length_col, scale = find_length_column(frame, None, None, source, option, naming=False)
    missing = [c for c in COLUMNS if c not in frame.columns]
    if missing:
        raise DataError(f"no column {', '.join(missing)} (columns: {', '.join(frame.columns)})",
                        source=source, where=option,
                        fix="a leveller record has the delivery and infeed readings and the "
                        "store's length clock (generate --sliver writes them)")  # fmt: skip
    values = {c: pd.to_numeric(frame[c], errors="coerce").to_numpy(np.float64) for c in COLUMNS}
    s = pd.to_numeric(frame[length_col], errors="coerce").to_numpy(np.float64) * scale
    bad = ~np.isfinite(s)
    for v in values.values():
        bad |= ~np.isfinite(v)
    if bad.any():
        raise DataError(f"row {int(np.argmax(bad)) + 2}: an empty or non-numeric cell",
                        source=source, where=option,
                        fix="a leveller record has no gaps; cut it at the gap")  # fmt: skip
    step = np.diff(s)
    h = float(np.median(step))
    if not (h > 0 and np.all(np.abs(step - h) <= 0.01 * h)):
        raise DataError(f"{length_col} is not increasing in even steps", source=source,
                        where=option, fix="the delivery readings come every few mm")  # fmt: skip
    record = LevellerRecord(s, values["linear_density_ktex"], values["infeed_ktex"],
                            values["fed_length_m"], values["time"], str(source))  # fmt: skip
    section = beside.sidecar if beside else {}
    return LevellerFile(record, *context_of(section), _true_point(section))


def _one_machine(frame: pd.DataFrame, machine: str | None, source: Path) -> pd.DataFrame:
    """The rows of ``machine`` in a log of several machines (its ``machine`` column); a log
    of several without a choice is refused by name (it read as a length that went back)."""
    names = sorted(str(n) for n in frame["machine"].unique()) if "machine" in frame else []
    if machine is None:
        if len(names) > 1:
            raise DataError(f"the log holds {len(names)} machines ({', '.join(names[:6])})",
                            source=source, where="--machine",
                            fix=f"pick one with --machine, e.g. --machine {names[0]}")  # fmt: skip
        return frame
    if machine not in names:
        raise DataError(f"no machine {machine!r} in the log" + (
            f" (it holds {', '.join(names[:6])})" if names else " (it has no machine column)"),
            source=source, where="--machine",
            fix="give a machine the log holds" if names else "leave --machine out")  # fmt: skip
    return frame[frame["machine"].astype(str) == machine].reset_index(drop=True)


def context_of(section: dict[str, Any]) -> tuple[LevellerSetting | None, bool,
                                                  dict[str, Any] | None, SliverSensor | None]:  # fmt: skip
    """What a sidecar's (or a served machine's) sliver description says: the leveller's
    setting (None: none named), whether there is a leveller, the fibres' description and the
    delivery sensor. Values out of range are not taken (a description from the wire is
    checked before it is trusted)."""
    setting, had = _setting(section)
    if setting is not None and not (
        math.isfinite(setting.action_point_mm) and 0 <= setting.action_point_mm <= 10_000
        and math.isfinite(setting.intensity) and 0 <= setting.intensity <= 2
        and (setting.reference_ktex is None
             or (math.isfinite(setting.reference_ktex) and 0 < setting.reference_ktex <= 1e3))):  # fmt: skip
        setting = None
    return setting, had, _described(section), _delivery(section)


def _setting(section: dict[str, Any]) -> tuple[LevellerSetting | None, bool]:
    lev = section.get("leveller")
    if "leveller" in section and lev is None:
        return None, False
    if not isinstance(lev, dict):
        return None, False
    try:
        ref = float(section["feed_ktex"]) * float(section["doublings"])
    except (KeyError, TypeError, ValueError):
        ref = None
    try:
        # the machine knows its drive's nominal time constant, not a fault's
        return LevellerSetting(float(lev["action_point_mm"]), float(lev["intensity"]), ref,
                               NOMINAL_DRIVE_S), True  # fmt: skip
    except (KeyError, TypeError, ValueError):
        return None, True


def _described(section: dict[str, Any]) -> dict[str, Any] | None:
    staple = section.get("staple")
    if not isinstance(staple, dict):
        return None
    try:  # lengths a fibre has (a description gone wrong names none)
        ok = 1 <= float(staple["mean_length_mm"]) <= 200 and 0 <= float(staple["length_cv"]) <= 1.5
    except (KeyError, TypeError, ValueError):
        return None
    return staple if ok else None


def _delivery(section: dict[str, Any]) -> SliverSensor | None:
    try:
        return SliverSensor(**section["delivery_sensor"])
    except (KeyError, TypeError, ValueError, ConfigError):  # none, or out of its ranges
        return None


def _true_point(section: dict[str, Any]) -> float | None:
    lev = section.get("leveller")
    try:
        return float(lev["true_action_point_mm"]) if isinstance(lev, dict) else None
    except (KeyError, TypeError, ValueError):
        return None
