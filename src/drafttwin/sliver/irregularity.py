"""Evenness of a sliver record: CV, U, CV at cut lengths, the variance-length curve.

All functions take a linear-density record on a uniform *delivered-length* grid (research/sliver.md
3.4): any unit proportional to mass per length, one value per grid step ``step_m`` (m). Each
value is read as the mean density over its grid step (a bin average), so a piece of ``m`` values
is a piece of sliver ``m * step_m`` long. The closed forms (Martindale's limit, the ideal
variance-length curve ``CV(L)`` of research/sliver.md 2 and 3.3) come from a
:class:`~drafttwin.sliver.staple.StapleDiagram`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from drafttwin.errors import DataError
from drafttwin.sliver.staple import StapleDiagram

MIN_POINTS = 100
"""Shortest record accepted, grid points."""

MIN_PIECES = 10
"""Fewest pieces a CV of piece means is computed from (else NaN)."""

CUT_LENGTHS_M: dict[str, float] = {"1 cm": 0.01, "1 m": 1.0, "3 m": 3.0, "5 m": 5.0}
"""The cut lengths an evenness report quotes (research/sliver.md 9.5), m."""


@dataclass(frozen=True)
class Evenness:
    """Evenness figures of one sliver record.

    Attributes:
        count_ktex: mean linear density, ktex (the record's unit read as ktex).
        cv_pct: coefficient of variation of the grid values, % (population CV: the point CV of
            the sliver averaged over one grid step).
        u_pct: mean absolute deviation / mean x 100, % (about CV / 1.25 for a Gaussian record).
        cv_cut_pct: CV of the means of consecutive, non-overlapping pieces of 1 cm, 1 m, 3 m and
            5 m (keys ``"1 cm"``, ``"1 m"``, ``"3 m"``, ``"5 m"``), %; a piece is
            ``round(L / step_m)`` grid values. NaN when fewer than 10 pieces fit in the record
            or the cut is shorter than half a grid step.
        martindale_cv_pct: Martindale's limit CV of a random sliver of this count, %, times
            ``sqrt(fibre_scale)``; None without a staple diagram.
        index_of_irregularity: ``cv_pct / martindale_cv_pct``; None without a staple diagram.
        length_m: tested length (number of values x step), m.
        step_m: grid step, m.
    """

    count_ktex: float
    cv_pct: float
    u_pct: float
    cv_cut_pct: dict[str, float]
    martindale_cv_pct: float | None
    index_of_irregularity: float | None
    length_m: float
    step_m: float

    def to_dict(self) -> dict[str, object]:
        """Plain JSON-able dict (NaN stays a float; the JSON writer maps it to null)."""
        return asdict(self)


def check_record(linear_density: np.ndarray, step_m: float) -> np.ndarray:
    """The record as a 1-D float64 array, refused (DataError naming ``--data``) when it has
    fewer than 100 values, non-finite values or a mean <= 0, or the step is not > 0."""
    rho = np.asarray(linear_density, dtype=np.float64)
    if not (math.isfinite(step_m) and step_m > 0):
        raise DataError(f"grid step {step_m} m: must be finite and > 0", where="--data",
                        fix="resample the record on a uniform delivered-length grid")  # fmt: skip
    if rho.ndim != 1 or rho.size < MIN_POINTS:
        raise DataError(f"the linear-density record has {rho.size} values in shape {rho.shape}; "
                        f"need a 1-D record of at least {MIN_POINTS}", where="--data",
                        fix="record a longer piece of sliver")  # fmt: skip
    bad = ~np.isfinite(rho)
    if bad.any():
        raise DataError(f"{int(bad.sum())} non-finite linear-density values (first at index "
                        f"{int(np.argmax(bad))})", where="--data",
                        fix="remove or interpolate the gaps first")  # fmt: skip
    mean = float(rho.mean())
    if mean <= 0:
        raise DataError(f"mean linear density {mean:g} <= 0", where="--data",
                        fix="give mass per length (positive), not a deviation")  # fmt: skip
    return rho


def _piece_points(length_m: float, step_m: float) -> int:
    """Grid values per piece of ``length_m`` (0 when the piece is under half a step)."""
    return int(round(length_m / step_m))


def _cv_of_pieces(rho: np.ndarray, points: int) -> float:
    """CV (%) of the means of consecutive non-overlapping pieces of ``points`` values (sample
    standard deviation, ddof 1); NaN when fewer than 10 pieces fit or ``points`` < 1."""
    if points < 1:
        return math.nan
    pieces = rho.size // points
    if pieces < MIN_PIECES:
        return math.nan
    means = rho[: pieces * points].reshape(pieces, points).mean(axis=1)
    return float(100.0 * means.std(ddof=1) / means.mean())


def evenness(linear_density: np.ndarray, step_m: float, staple: StapleDiagram | None = None,
             fibre_scale: float = 1.0) -> Evenness:  # fmt: skip
    """Evenness of a sliver record (see :class:`Evenness`).

    Args:
        linear_density: values on a uniform delivered-length grid, any unit proportional to
            mass per length (the count is reported as if it were ktex).
        step_m: grid step, m.
        staple: the fibres, for Martindale's limit and the index of irregularity.
        fibre_scale: fibres lumped into one simulated fibre (>= 1): the random variance grows
            by this factor, so the limit is ``martindale * sqrt(fibre_scale)``.
    """
    rho = check_record(linear_density, step_m)
    mean = float(rho.mean())
    cv = float(100.0 * rho.std() / mean)
    u = float(100.0 * np.mean(np.abs(rho - mean)) / mean)
    cuts = {
        key: _cv_of_pieces(rho, _piece_points(cut, step_m)) for key, cut in CUT_LENGTHS_M.items()
    }
    limit = None if staple is None else staple.martindale_cv_pct(mean) * math.sqrt(fibre_scale)
    return Evenness(
        count_ktex=mean,
        cv_pct=cv,
        u_pct=u,
        cv_cut_pct=cuts,
        martindale_cv_pct=limit,
        index_of_irregularity=None if limit is None else cv / limit,
        length_m=rho.size * step_m,
        step_m=float(step_m),
    )


def variance_length_curve(
    linear_density: np.ndarray, step_m: float, lengths_m: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The variance-length curve ``CV(L)`` of a record: CV (%) of the means of consecutive,
    non-overlapping pieces of length ``L``.

    Args:
        linear_density: values on a uniform grid of ``step_m`` (m).
        step_m: grid step, m.
        lengths_m: piece lengths, m; default 30 log-spaced lengths from 2 grid steps to a tenth
            of the record (repeats after rounding to whole steps dropped).

    Returns:
        ``(lengths_m, cv_pct)``: the lengths actually used, ``round(L / step) * step`` (m), and
        the CV at each, % (NaN where fewer than 10 pieces fit or ``L`` < half a step).
    """
    rho = check_record(linear_density, step_m)
    if lengths_m is None:
        wanted = np.geomspace(2 * step_m, rho.size * step_m / MIN_PIECES, 30)
        points = np.unique(np.rint(wanted / step_m).astype(np.int64))
    else:
        points = np.rint(np.asarray(lengths_m, dtype=np.float64) / step_m).astype(np.int64)
    cv = np.array([_cv_of_pieces(rho, int(p)) for p in points.ravel()], dtype=np.float64)
    return points.astype(np.float64).ravel() * step_m, cv


def variance_length_factor(staple: StapleDiagram, lengths_m: np.ndarray) -> np.ndarray:
    """``B(L) = CV^2(L) / CV_lim^2`` of a random sliver (research/sliver.md 3.3):
    ``B(L) = (2/L^2) int_0^L (L-u) rho(u) du`` with ``rho(u) = E[(l-u)^+] / E[l]``.

    Exact: for one fibre length ``l``, ``J(l) = int_0^L (L-u)(l-u)^+ du`` is ``L l^2/2 - l^3/6``
    (``l <= L``) or ``l L^2/2 - L^3/6`` (``l >= L``), and ``B = 2 E[J] / (L^2 E[l])``. ``E[J]`` is
    integrated in closed form over each class with lengths uniform within it (the same spread
    as :meth:`StapleDiagram.moment`), so no class-centre or quadrature error enters.
    ``lengths_m`` (m, > 0) may have any shape; the result has the same shape.
    """
    length_mm = np.asarray(lengths_m, dtype=np.float64) * 1000.0
    if np.any(~np.isfinite(length_mm)) or np.any(length_mm <= 0):
        raise ValueError("piece lengths must be finite and > 0")
    big_l = length_mm.reshape(-1, 1)
    half = staple.class_width_mm / 2
    lo, hi = staple.lengths_mm - half, staple.lengths_mm + half

    def short(a: np.ndarray, b: np.ndarray) -> np.ndarray:  # int_a^b (L l^2/2 - l^3/6) dl
        j: np.ndarray = big_l * (b**3 - a**3) / 6 - (b**4 - a**4) / 24
        return j

    def long(a: np.ndarray, b: np.ndarray) -> np.ndarray:  # int_a^b (l L^2/2 - L^3/6) dl
        j: np.ndarray = big_l**2 * (b**2 - a**2) / 4 - big_l**3 * (b - a) / 6
        return j

    cut = np.clip(big_l, lo, hi)
    per_class = (short(lo, cut) + long(cut, hi)) / (hi - lo)
    expected_j: np.ndarray = per_class @ staple.weights
    b = 2.0 * expected_j / (length_mm.ravel() ** 2 * staple.mean_length_mm)
    return b.reshape(length_mm.shape)


def ideal_variance_length_cv_pct(staple: StapleDiagram, count_ktex: float, lengths_m: np.ndarray,
                                 fibre_scale: float = 1.0) -> np.ndarray:  # fmt: skip
    """Ideal ``CV(L)``, %, of a random sliver of ``count_ktex`` from ``staple`` at piece lengths
    ``lengths_m`` (m): ``CV_lim * sqrt(fibre_scale) * sqrt(B(L))`` (research/sliver.md 3.3; see
    :func:`variance_length_factor`). At ``L`` = one grid step it is the point CV of a record of
    bin averages."""
    limit = staple.martindale_cv_pct(count_ktex) * math.sqrt(fibre_scale)
    cv_pct: np.ndarray = limit * np.sqrt(variance_length_factor(staple, lengths_m))
    return cv_pct
