"""An open-loop autoleveller: the infeed scanning rollers measure, the main draft levels.

As on a Rieter RSB (research/sliver.md section 6): the scanning rollers read the fed slivers'
thickness ``scan_ahead_mm`` before the back nip (:class:`InfeedSensor`); a store clocked by
the feeding rollers' own travel hands each reading on when that much fed sliver has passed
(the *action point* setting, mm of fed sliver from the scanning rollers: the number a mill
types); there the rollers upstream of the main draft (second, third and back together, so
the break draft stays) are commanded slower by the measured excess times the intensity, and
the regulating drive follows the command with its own lag (:class:`RegulatingDrive`). The
delivery speed stays.

In ideal drafting the main draft acts on a fibre when its leading end reaches the front nip,
and a reading of the fed sliver's mass stands for the fibres that cover the scanned place,
whose leading ends lie on average half a mass-mean fibre length ahead of it. So the *true
action point* (:func:`true_action_point_mm`) is the scanning rollers' distance to the back
nip plus the zones' transit in feeding-roller travel, less half the mass-mean fibre length;
a setting off it applies each correction to other material, and the CV against the setting
is V-shaped around it (check T10). The drive's lag moves the best setting a little shorter
(``tau`` times the feeding speed: 3 mm at 5 ms and 39 m/min).

Faults: a drifting infeed sensor (``drift_pct_per_min``: the reading's gain drifts, so the
leveller levels to a drifting count), a wrong action point (the setting), a sluggish drive (a
longer time constant).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from scipy.ndimage import uniform_filter1d

from drafttwin.errors import ConfigError
from drafttwin.sliver import kernel as K
from drafttwin.sliver.staple import StapleDiagram

MIN_FACTOR, MAX_FACTOR = 0.5, 2.0
"""The feeding rollers' speed range under the leveller (a servo's range)."""
NOMINAL_DRIVE_S = 0.005
"""The regulating drive's time constant, s (assumption: a servo drive of a few ms; no public
figure was found)."""


@dataclass(frozen=True)
class InfeedSensor:
    """The infeed scanning rollers.

    Attributes:
        averaging_mm: contact length over which a reading averages the fed slivers (centred
            on the scanning nip), mm of fed sliver.
        noise: relative white noise of one reading.
        pitch_mm: fed length between readings (the store's clock), mm; a reading holds until
            the next.
        scan_ahead_mm: distance from the scanning rollers to the back nip along the sliver, mm.
        drift_pct_per_min: a fault: the reading's gain drifts by this much per minute from
            the record's start, %.
    """

    averaging_mm: float = 20.0
    noise: float = 0.003
    pitch_mm: float = 1.0
    scan_ahead_mm: float = 600.0
    drift_pct_per_min: float = 0.0

    def __post_init__(self) -> None:
        _refuse_out_of_range("infeed sensor", "--leveller-fault", (
            ("averaging", self.averaging_mm, "mm", 0 < self.averaging_mm <= 1000, "0-1000 mm"),
            ("noise", self.noise, "", 0 <= self.noise < 0.5, "below 0.5"),
            ("pitch", self.pitch_mm, "mm", 0.1 <= self.pitch_mm <= 100, "0.1-100 mm"),
            ("scan ahead", self.scan_ahead_mm, "mm", 0 <= self.scan_ahead_mm <= 5000,
             "0-5000 mm"),
            ("drift", self.drift_pct_per_min, "% per minute", abs(self.drift_pct_per_min) <= 10,
             "within +-10 % per minute"),
        ))  # fmt: skip

    def readings(self, relative: np.ndarray, p0_mm: float, step_mm: float,
                 staple: StapleDiagram, rng: np.random.Generator,
                 fed_mm_per_s: float) -> InfeedReadings:  # fmt: skip
        """The readings of the feed whose fibres' leading ends arrive at the relative rate
        ``relative`` on the fed grid ``p0_mm + step_mm k``: its mass (the rate smoothed over
        the fibre lengths behind each place), averaged over the contact length, one reading
        per pitch with the sensor's noise and drift (time from the fed position at
        ``fed_mm_per_s``; the record starts at fed position 0)."""
        kernel = mass_kernel(staple, step_mm)
        # before the grid the feed runs on as at its start (no edge of empty sliver)
        padded = np.concatenate([np.full(kernel.size - 1, relative[0]), relative])
        mass = np.convolve(padded, kernel, mode="valid")
        width = max(1, int(round(self.averaging_mm / step_mm)))
        seen = uniform_filter1d(mass, width, mode="nearest")
        q = p0_mm + self.pitch_mm * np.arange(int((relative.size - 1) * step_mm / self.pitch_mm))
        x = np.interp(q, p0_mm + step_mm * np.arange(relative.size), seen)
        minutes = np.maximum(q - self.scan_ahead_mm, 0.0) / max(fed_mm_per_s, 1e-9) / 60.0
        x = x * (1.0 + self.drift_pct_per_min / 100.0 * minutes)
        x = x * (1.0 + self.noise * rng.standard_normal(x.size))
        return InfeedReadings(float(q[0]), self.pitch_mm, x)


@dataclass(frozen=True)
class InfeedReadings:
    """The infeed sensor's readings, relative to the feed's nominal count (1 = nominal).

    Attributes:
        q0_mm: fed position of the first reading, mm (0 at the record's start).
        pitch_mm: fed length between readings, mm.
        relative: the readings.
    """

    q0_mm: float
    pitch_mm: float
    relative: np.ndarray

    def at(self, q_mm: np.ndarray) -> np.ndarray:
        """The reading held at fed positions ``q_mm`` (the last one taken at or before)."""
        k = np.floor((np.asarray(q_mm) - self.q0_mm) / self.pitch_mm).astype(np.int64)
        held: np.ndarray = self.relative[np.clip(k, 0, self.relative.size - 1)]
        return held


@dataclass(frozen=True)
class RegulatingDrive:
    """The drive of the feeding rollers: a first-order lag to the leveller's command.

    Attributes:
        time_constant_s: its time constant, s (a sluggish drive: a longer one).
    """

    time_constant_s: float = NOMINAL_DRIVE_S

    def __post_init__(self) -> None:
        if not 0 <= self.time_constant_s <= 10:
            raise ConfigError(f"regulating drive time constant {self.time_constant_s} s",
                              where="--leveller-fault", fix="give 0-10 s")  # fmt: skip


@dataclass(frozen=True)
class Levelling:
    """What the leveller did over a drafting run.

    Attributes:
        readings: the infeed sensor's readings it acted on.
        action_point_mm: its setting (fed mm from the scanning rollers).
        true_action_point_mm: the true action point in the same frame.
        time_s: the time grid of the rollers' surfaces (run-in included), s.
        back_mm: the feeding (back) roller's levelled surface length there, mm (0 at the
            record's start): the store's length clock.
        factor: the drive's speed factor there.
    """

    readings: InfeedReadings
    action_point_mm: float
    true_action_point_mm: float
    time_s: np.ndarray
    back_mm: np.ndarray
    factor: np.ndarray


@dataclass(frozen=True)
class Autoleveller:
    """Open-loop levelling through the main draft.

    Attributes:
        intensity: fraction of the measured excess corrected (1: all of it).
        action_offset_mm: the setting's error against the true action point, mm of fed
            sliver (positive: each correction reaches material that far behind the measured
            one); used where ``action_point_mm`` is None.
        action_point_mm: the setting in the machine's frame (fed mm from the scanning
            rollers), or None: the true action point plus ``action_offset_mm``.
        sensor: the infeed scanning rollers.
        drive: the regulating drive.
    """

    intensity: float = 1.0
    action_offset_mm: float = 0.0
    action_point_mm: float | None = None
    sensor: InfeedSensor = field(default_factory=InfeedSensor)
    drive: RegulatingDrive = field(default_factory=RegulatingDrive)

    def __post_init__(self) -> None:
        point = self.action_point_mm
        _refuse_out_of_range("autoleveller", "--leveller", (
            ("intensity", self.intensity, "", 0 <= self.intensity <= 2, "0-2"),
            ("action offset", self.action_offset_mm, "mm", abs(self.action_offset_mm) <= 5000,
             "within +-5000 mm"),
            ("action point", point, "mm", point is None or 0 <= point <= 10000, "0-10000 mm"),
        ))  # fmt: skip

    @classmethod
    def parse(cls, text: str, faults: Sequence[str] = ()) -> Autoleveller:
        """``INTENSITY[,ACTION_OFFSET_MM]`` (``--leveller``) with faults (``--leveller-fault``,
        each ``infeed-drift=PCT_PER_MIN`` or ``sluggish-drive=TIME_CONSTANT_MS``; a wrong
        action point is the offset)."""
        try:
            parts = [float(x) for x in text.split(",")]
        except ValueError:
            parts = []
        if len(parts) not in (1, 2) or not all(math.isfinite(x) for x in parts):
            raise ConfigError(f"'{text}' is not INTENSITY[,ACTION_OFFSET_MM]", where="--leveller",
                              fix="e.g. 1 or 1,15")  # fmt: skip
        sensor, drive = InfeedSensor(), RegulatingDrive()
        for fault in faults:
            name, _, value = fault.partition("=")
            try:
                number = float(value)
            except ValueError:
                number = math.nan
            if name.strip() == "infeed-drift" and math.isfinite(number):
                sensor = replace(sensor, drift_pct_per_min=number)
            elif name.strip() == "sluggish-drive" and math.isfinite(number):
                drive = RegulatingDrive(number / 1000.0)
            else:
                raise ConfigError(f"cannot read '{fault}'", where="--leveller-fault",
                                  fix="infeed-drift=PCT_PER_MIN or sluggish-drive=MS (the "
                                  f"drive's time constant; nominal {1000 * NOMINAL_DRIVE_S:g} "
                                  "ms)")  # fmt: skip
        return cls(parts[0], parts[1] if len(parts) == 2 else 0.0, sensor=sensor, drive=drive)

    @property
    def sensor_mm(self) -> float:
        """The scanning rollers' averaging length, mm of fed sliver."""
        return self.sensor.averaging_mm

    def setting_mm(self, true_mm: float) -> float:
        """The action point setting (fed mm from the scanning rollers), within 0-10000 mm as
        every reader of a setting takes it (``--leveller 1,-1000`` had made a machine at
        -298 mm that `sliver level` and the twin then read as one without a setting)."""
        setting = (
            true_mm + self.action_offset_mm
            if self.action_point_mm is None
            else self.action_point_mm
        )
        if not 0.0 <= setting <= 10_000.0:
            raise ConfigError(f"the action point setting would be {setting:.0f} mm (the true "
                              f"{true_mm:.0f} mm {self.action_offset_mm:+g} mm): a setting lies "
                              "within 0-10000 mm", where="--leveller",
                              fix=f"an offset from {-true_mm:.0f} to {10_000 - true_mm:.0f} mm")  # fmt: skip
        return setting

    def record(self, true_mm: float) -> dict[str, Any]:
        """The settings and the true action point, for a sidecar (the machine's frame)."""
        setting = self.setting_mm(true_mm)
        return {"intensity": self.intensity, "action_point_mm": setting,
                "true_action_point_mm": true_mm, "action_offset_mm": setting - true_mm,
                "reference": "the feed's nominal count", "infeed_sensor": asdict(self.sensor),
                "drive": asdict(self.drive)}  # fmt: skip

    def levelled(self, surface: np.ndarray, time_s: np.ndarray, p_grid: np.ndarray,
                 relative: np.ndarray, staple: StapleDiagram, gauges_mm: np.ndarray,
                 rng: np.random.Generator) -> tuple[np.ndarray, Levelling]:  # fmt: skip
        """The surface lengths (mm, ``(m, 4)`` on the uniform time grid ``time_s``, 0 at the
        record's start) with second, third and back roller driven by the leveller, for a feed whose
        leading ends arrive at the relative rate ``relative`` on ``p_grid`` (fed mm); the
        zones' gauges ``(main, middle, break)`` mm give the true action point."""
        step_s = float(time_s[1] - time_s[0])
        travel = surface[-1] - surface[0]
        fed_speed = float(travel[K.BACK]) / (step_s * (surface.shape[0] - 1))
        drafts = {"break": float(travel[K.THIRD] / travel[K.BACK]),
                  "middle": float(travel[K.SECOND] / travel[K.THIRD])}  # fmt: skip
        true_mm = true_action_point_mm(gauges_mm, drafts, staple, self.sensor.scan_ahead_mm)
        setting = self.setting_mm(true_mm)
        step = float(p_grid[1] - p_grid[0])
        readings = self.sensor.readings(relative, float(p_grid[0]), step, staple, rng, fed_speed)
        tau = self.drive.time_constant_s
        a = 1.0 if tau == 0 else -math.expm1(-step_s / tau)
        params = np.array([readings.q0_mm, readings.pitch_mm, self.sensor.scan_ahead_mm - setting,
                           self.intensity, a, MIN_FACTOR, MAX_FACTOR])  # fmt: skip
        out = np.empty_like(surface)
        factor = np.empty(surface.shape[0])
        K.level_surface(np.ascontiguousarray(surface), readings.relative, params, out, factor)
        return out, Levelling(readings, setting, true_mm, time_s, out[:, K.BACK].copy(), factor)


def true_action_point_mm(gauges_mm: np.ndarray, drafts: dict[str, float], staple: StapleDiagram,
                         scan_ahead_mm: float) -> float:  # fmt: skip
    """The true action point, mm of fed sliver from the scanning rollers: the distance to
    the back nip, plus the break, middle and main zones' gauges in feeding-roller travel
    (``g_break + g_middle / D_break + g_main / (D_break D_middle)``: the leveller keeps those
    drafts), less half the mass-mean fibre length ``E[l^2] / (2 E[l])`` (a reading of mass
    stands for fibres whose leading ends lie that far ahead on average)."""
    main, middle, brk = (float(g) for g in gauges_mm)
    transit = brk + middle / drafts["break"] + main / (drafts["break"] * drafts["middle"])
    return scan_ahead_mm + transit - staple.mass_mean_length_mm / 2


def mass_kernel(staple: StapleDiagram, step_mm: float) -> np.ndarray:
    """Weights (sum 1) of the mass at a place from the fibres' leading ends ``u = 0, step,
    ...`` mm ahead of it: ``P(l > u) / E[l]`` over the staple diagram (a fibre covers the
    length behind its leading end)."""
    u = np.arange(0.0, float(staple.lengths_mm[-1] + staple.class_width_mm) + step_mm, step_mm)
    h = staple.class_width_mm / 2
    lo, hi = staple.lengths_mm - h, staple.lengths_mm + h
    # P(l > u) with lengths uniform within each class
    inside = np.clip((hi[None, :] - u[:, None]) / (hi - lo)[None, :], 0.0, 1.0)
    survival = inside @ staple.weights
    return np.asarray(survival / survival.sum(), dtype=np.float64)


def _refuse_out_of_range(what: str, where: str,
                         fields: Sequence[tuple[str, object, str, bool, str]]) -> None:  # fmt: skip
    """One error naming only the fields out of their range (name, value, unit, ok, range)."""
    bad = [f for f in fields if not f[3]]
    if bad:
        raise ConfigError(f"{what} " + ", ".join(f"{n} {v:g}{' ' + u if u else ''}"
                                                 for n, v, u, _, _ in bad),
                          where=where, fix="; ".join(f"{n} {r}" for n, _, _, _, r in bad))  # fmt: skip
