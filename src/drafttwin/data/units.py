"""Units of measured channels: a header's or a user's unit, defaults, and the rpm heuristics.

A channel's unit comes from ``units=`` (declared), from its header (``y [m]``, ``front_rpm``, or
the units stored in a Parquet file written by drafttwin), or from its name: the FA320A rollers
and ``motor`` are in rpm, ``supply_hz`` in Hz, anything else is undeclared (``""``). A declared
unit that contradicts the header's is refused. The plausibility heuristics (running speed
range, sign, front faster than back, ratio to nominal speeds) run on channels in rpm only.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from drafttwin._constants import ROLLERS
from drafttwin.errors import DataError

RPM = "rpm"
PLAUSIBLE_RPM: tuple[float, float] = (10.0, 10_000.0)
"""Plausible running speed range of drawing-frame bottom rollers, rpm."""

RPM_UNITS = frozenset({"rpm", "r/min", "1/min", "min^-1", "min-1", "u/min", "rev/min"})
TO_RPM: dict[str, str] = {  # how to convert a speed unit to rpm
    "rad/s": "multiply by 60/(2*pi) = 9.5493",
    "rev/s": "multiply by 60",
    "rps": "multiply by 60",
    "hz": "multiply by 60",
    "deg/s": "divide by 6",
    "m/min": "divide by pi * roller diameter in m",
    "m/s": "multiply by 60 and divide by pi * roller diameter in m",
}
_DEFAULT_UNITS = {**dict.fromkeys(ROLLERS, RPM), "motor": RPM, "supply_hz": "Hz"}


def normalise_unit(unit: str) -> str:
    """A comparable spelling: no spaces, lower case, every rpm synonym as ``rpm``."""
    low = unit.replace(" ", "").lower()
    return RPM if low in RPM_UNITS else low


def is_rpm(unit: str | None) -> bool:
    return bool(unit) and normalise_unit(str(unit)) == RPM


def default_unit(name: str) -> str:
    """``rpm`` for the four rollers and the motor, ``Hz`` for ``supply_hz``, else ``""``."""
    return _DEFAULT_UNITS.get(name, "")


def refuse_unit(header: str, unit: str, source: str | Path) -> None:
    """Refuse a roller or motor column whose header declares a unit other than rpm."""
    if is_rpm(unit):
        return
    hint = TO_RPM.get(normalise_unit(unit), "convert to rpm")
    raise DataError(
        f"column is in {unit}, drafttwin needs roller speeds in rpm",
        source=source,
        where=f"column '{header}'",
        fix=f"{hint} to get rpm, and name the column without the unit (e.g. 'front')",
    )


def resolve_unit(
    name: str, header: str, header_unit: str | None, declared: str | None, source: str | Path
) -> str:
    """The unit of channel ``name`` read from column ``header``.

    A declared unit wins but must agree with the header's; without a declaration the header's
    unit is taken, and for a channel that is rpm by name (a roller, the motor) a header in
    another unit is refused with the conversion to rpm.
    """
    if declared:
        if header_unit and normalise_unit(header_unit) != normalise_unit(declared):
            raise DataError(
                f"the header gives the unit '{header_unit}' but units declares '{declared}' "
                f"for '{name}'",
                source=source,
                where=f"column '{header}'",
                fix="correct the unit in the header or in units= (they must agree)",
            )
        return RPM if is_rpm(declared) else declared
    default = default_unit(name)
    if not header_unit:
        return default
    if default and normalise_unit(header_unit) != normalise_unit(default):
        if is_rpm(default):
            refuse_unit(header, header_unit, source)
        raise DataError(
            f"column is in {header_unit}, but '{name}' is in {default} by name",
            source=source,
            where=f"column '{header}'",
            fix=f"convert the column to {default}, or map it to another name with --columns",
        )
    return RPM if is_rpm(header_unit) else header_unit


# ------------------------------------------------------------------------- rpm heuristics


def _nonzero(x: np.ndarray) -> np.ndarray:
    a = x[np.isfinite(x)]
    nonzero: np.ndarray = a[a != 0]
    return nonzero


def _running_median(x: np.ndarray) -> float:
    """Median of |x| over finite, non-zero samples (stops excluded); NaN if none."""
    a = np.abs(_nonzero(x))
    return float(np.median(a)) if a.shape[0] else float("nan")


def check_units(
    rpm: np.ndarray,
    names: Sequence[str],
    source: str | Path,
    *,
    nominal_rpm: dict[str, float] | None = None,
    trained_rpm: dict[str, tuple[float, float]] | None = None,
    diameters_mm: dict[str, float] | None = None,
    plausible: tuple[float, float] = PLAUSIBLE_RPM,
    row_label: Callable[[int], str] = lambda i: f"row {i + 1}",
) -> dict[str, float]:
    """Refuse speeds in rpm that look like another unit; return the running medians (rpm).

    ``rpm`` holds one column per name in ``names`` (only channels in rpm). Heuristics: a
    channel that mostly runs backwards (negative median of its non-zero samples: a reversed
    sign); a running median outside the plausible rpm range of drafting rollers; a front
    (delivery) roller slower than the back roller (drafting makes the front fastest, so the
    columns are swapped); and, when nominal speeds are given, a median whose ratio to the
    nominal speed matches a unit factor (rad/s, rev/s, deg/s, or m/min with known diameters);
    with a model's trained range (``trained_rpm``: (min, max) per channel), a median outside
    it that lies inside it once converted from such a unit.
    Per sample (:func:`check_samples`): no speed beyond what any roller can reach, and no
    sample running backwards by more than the noise of a stop.
    """
    for j, name in enumerate(names):
        running = _nonzero(rpm[:, j])
        if running.shape[0] and float(np.median(running)) < 0:
            _refuse_negative(name, float(np.median(running)), source)
    medians = {r: _running_median(rpm[:, j]) for j, r in enumerate(names)}
    for r, med in medians.items():
        if np.isfinite(med) and not plausible[0] <= med <= plausible[1]:
            _refuse_range(r, med, plausible, source)
    if "front" in medians and "back" in medians and medians["front"] < medians["back"]:
        raise DataError(
            f"front roller median {medians['front']:.4g} rpm is slower than back roller "
            f"{medians['back']:.4g} rpm, but drafting makes the front (delivery) roller fastest",
            source=source,
            where="columns 'front', 'back'",
            fix="the roller columns look swapped or reversed: map them, e.g. "
            "--columns front=back,back=front (file column = roller)",
        )
    _refuse_swapped(medians, nominal_rpm or {}, source)  # before a unit is guessed per column
    for r, nominal in (nominal_rpm or {}).items():
        if r in medians and np.isfinite(medians[r]) and nominal > 0:
            _compare_nominal(r, medians[r], nominal, (diameters_mm or {}).get(r), source)
    for r, (lo, hi) in (trained_rpm or {}).items():
        if r in medians and np.isfinite(medians[r]) and 0 < lo <= hi:
            _compare_trained(r, medians[r], (lo, hi), (diameters_mm or {}).get(r), source)
    check_samples(rpm, names, medians, source, row_label, plausible)
    return medians


SPEED_CEILING_FACTOR = 10.0
"""A sample above this many times the plausible maximum is no speed at all (a bit error)."""
REVERSE_TOLERANCE = (10.0, 0.05)
"""A sample may run backwards by at most max(10 rpm, 5 % of the running median): torsional
swing at a stop (the plant's start-ups reach -0.6 rpm); a drawing frame cannot run its
rollers backwards further than that."""


def check_samples(
    rpm: np.ndarray,
    names: Sequence[str],
    medians: dict[str, float],
    source: str | Path,
    row_label: Callable[[int], str],
    plausible: tuple[float, float] = PLAUSIBLE_RPM,
) -> None:
    """Refuse single samples that no drafting roller can produce (named by row)."""
    ceiling = SPEED_CEILING_FACTOR * plausible[1]
    for j, name in enumerate(names):
        x = rpm[:, j]
        med = medians.get(name, float("nan"))
        floor = -max(REVERSE_TOLERANCE[0], REVERSE_TOLERANCE[1] * (med if med == med else 0.0))
        with np.errstate(invalid="ignore"):
            bad = np.flatnonzero((x > ceiling) | (x < floor))
        if bad.shape[0]:
            i = int(bad[0])
            high = x[i] > ceiling
            limit = f"above {ceiling:g} rpm" if high else f"below {floor:.4g} rpm (backwards)"
            skip = "the speeds are not in rpm" if high else "the machine really reverses"
            raise DataError(
                f"sample {x[i]:.6g} rpm is {limit}, which no drafting roller reaches "
                f"({bad.shape[0]} such sample(s))",
                source=source,
                where=f"column '{name}', {row_label(i)}",
                fix="remove or blank the corrupted samples (an empty cell is read as missing "
                f"and filled by the preprocessing); if {skip}, skip this check "
                "(check_units=False / --no-unit-check)",
            )


def _refuse_negative(name: str, med: float, source: str | Path) -> None:
    raise DataError(
        f"the running speed is negative (median {med:.4g} rpm over the non-zero samples)",
        source=source,
        where=f"column '{name}'",
        fix="the encoder counts backwards: flip the sign of the column; if the machine really "
        "runs backwards, skip this check (check_units=False / --no-unit-check)",
    )


def _refuse_range(
    name: str, med: float, plausible: tuple[float, float], source: str | Path
) -> None:
    if med < plausible[0]:
        guess = (
            f"rev/s (x60 -> {med * 60:.4g} rpm) or rad/s (x60/(2*pi) = x9.5493 -> "
            f"{med * 60 / (2 * math.pi):.4g} rpm)"
        )
    else:
        guess = "encoder counts, mrad/s or deg/min rather than rpm"
    what = "drafting rollers" if name in ROLLERS else "running speeds"
    raise DataError(
        f"median running speed {med:.4g} is outside the plausible range "
        f"{plausible[0]:g}-{plausible[1]:g} rpm of {what}; it looks like {guess}",
        source=source,
        where=f"column '{name}'",
        fix="convert the column to rpm; if the speeds really are in rpm, skip this check "
        "(check_units=False / --no-unit-check)",
    )


def _unit_factors(diameter_mm: float | None) -> dict[str, float]:
    """What a speed in rpm becomes in each other unit (x factor)."""
    candidates = {"rad/s": 2 * math.pi / 60, "rev/s": 1 / 60, "deg/s": 6.0}
    if diameter_mm:
        candidates["m/min"] = math.pi * diameter_mm / 1000.0
    return candidates


def _compare_trained(
    name: str, med: float, trained: tuple[float, float], diameter_mm: float | None,
    source: str | Path,
) -> None:  # fmt: skip
    """A median outside the trained range that falls inside it in another unit (a model
    without physics has no other level to go by)."""
    _refuse_other_unit(name, med, trained, diameter_mm, source,
                       f"lies outside the {trained[0]:.4g}-{trained[1]:.4g} rpm the model was "
                       "trained on")  # fmt: skip


def _compare_nominal(
    name: str, med: float, nominal: float, diameter_mm: float | None, source: str | Path
) -> None:
    _refuse_other_unit(name, med, (nominal, nominal), diameter_mm, source,
                       f"is {med / nominal:.3g} x the nominal {nominal:.4g} rpm")  # fmt: skip


def _refuse_swapped(medians: Mapping[str, float], nominal_rpm: Mapping[str, float],
                    source: str | Path) -> None:  # fmt: skip
    """Refuse a column mapped to the wrong roller: the rollers turn in fixed ratios at any
    set-point, so each median over its nominal is the same speed factor (within 15 %); a
    column more than 15 % off the others' factor that runs as another roller would at it
    is that roller's (a front column 4x slow: the second's)."""
    factor = {r: medians[r] / n for r, n in nominal_rpm.items()
              if n > 0 and r in medians and np.isfinite(medians[r]) and medians[r] > 0}  # fmt: skip
    if len(factor) < 3:
        return
    k0 = float(np.median(list(factor.values())))
    for name, k in factor.items():
        if k0 / 1.15 <= k <= k0 * 1.15:
            continue
        med = medians[name]
        other = next((o for o, n in nominal_rpm.items()
                      if o != name and o in factor and n * k0 / 1.15 <= med <= n * k0 * 1.15),
                     None)  # fmt: skip
        if other is None:
            continue
        raise DataError(
            f"median running speed {med:.4g} rpm is {k / k0:.3g} x what the other columns' "
            f"speeds give it ({nominal_rpm[name] * k0:.4g} rpm) and runs as '{other}' would",
            source=source,
            where=f"column '{name}'",
            fix=f"the columns look swapped: map them, e.g. --columns {name}={other},"
            f"{other}={name} (file column = roller); if they are right, skip this check "
            "(--no-unit-check)",
        )


def _refuse_other_unit(
    name: str, med: float, level: tuple[float, float], diameter_mm: float | None,
    source: str | Path, said: str,
) -> None:  # fmt: skip
    """Refuse a median more than 15 % outside ``level`` (rpm, a range) that lies within 15 %
    of it once read as rad/s, rev/s, deg/s (or m/min with a diameter)."""
    lo, hi = level[0] / 1.15, level[1] * 1.15
    if lo <= med <= hi:
        return
    matches = [u for u, f in _unit_factors(diameter_mm).items() if lo * f <= med <= hi * f]
    if matches:
        raise DataError(
            f"median running speed {med:.4g} {said}, which matches a column in "
            f"{' or '.join(matches)}",
            source=source,
            where=f"column '{name}'",
            fix="convert to rpm: " + "; ".join(f"{u}: {TO_RPM[u]}" for u in matches),
        )
