"""The fibres of a sliver: the staple diagram (length distribution) and the fineness.

A :class:`StapleDiagram` holds a number-weighted fibre-length distribution on classes of a few
tenths of a millimetre, and the fibres' fineness (dtex) with its spread. Everything the sliver
layer computes in closed form (Martindale's limit, the ideal spectrum, the variance-length
curve, the fibre-length filter of a speed modulation) takes its moments from here, and the
drafting simulator draws its fibres from the same classes, so simulation and closed forms
describe one material.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from drafttwin.errors import ConfigError, DataError

CLASS_WIDTH_MM = 0.25
"""Width of a length class of the built-in distributions, mm (fibres are drawn uniformly
within their class, so no length is favoured)."""


@dataclass(frozen=True)
class StapleDiagram:
    """Fibre length distribution (number-weighted) and fineness of one fibre material.

    Attributes:
        lengths_mm: class centres, mm, increasing, shape ``(k,)``.
        weights: number fraction of fibres in each class (sums to 1).
        class_width_mm: width of each class, mm (fibres are spread uniformly within it).
        fineness_dtex: mean linear density of one fibre, dtex (g per 10 km).
        fineness_cv: coefficient of variation of one fibre's linear density (0.25 = 25 %).
        name: what the material is, for reports.
    """

    lengths_mm: np.ndarray
    weights: np.ndarray
    class_width_mm: float
    fineness_dtex: float
    fineness_cv: float = 0.0
    name: str = "fibres"
    _moments: dict[int, float] = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        lengths = np.asarray(self.lengths_mm, dtype=np.float64)
        weights = np.asarray(self.weights, dtype=np.float64)
        where = f"staple diagram '{self.name}'"
        if lengths.ndim != 1 or lengths.shape != weights.shape or lengths.size == 0:
            raise ConfigError("lengths and weights must be 1-D of one size", source=where)
        if not (np.all(np.isfinite(lengths)) and np.all(lengths > 0)):
            raise ConfigError("fibre lengths must be finite and > 0 mm", source=where)
        if np.any(np.diff(lengths) <= 0):
            raise ConfigError("length classes must increase", source=where)
        if not (np.all(np.isfinite(weights)) and np.all(weights >= 0) and weights.sum() > 0):
            raise ConfigError("class weights must be finite, >= 0, not all 0", source=where)
        if not (0 < self.class_width_mm <= 10 and 0 < self.fineness_dtex <= 100):
            raise ConfigError("class width must be in (0, 10] mm and fineness in (0, 100] dtex",
                              source=where)  # fmt: skip
        if not 0 <= self.fineness_cv <= 1.5:
            raise ConfigError("fineness CV must be in [0, 1.5] (a fraction)", source=where)
        if lengths[0] - self.class_width_mm / 2 < 0:
            raise ConfigError("the shortest class reaches below 0 mm", source=where)
        object.__setattr__(self, "lengths_mm", lengths)
        object.__setattr__(self, "weights", weights / weights.sum())

    # ---- construction -------------------------------------------------------------------
    @classmethod
    def gamma(cls, mean_length_mm: float, length_cv: float, fineness_dtex: float,
              fineness_cv: float = 0.0, name: str = "fibres",
              class_width_mm: float = CLASS_WIDTH_MM) -> StapleDiagram:  # fmt: skip
        """A gamma-shaped length distribution of the given number mean (mm) and CV (a
        fraction; 0 gives fibres of one length), discretised on classes of ``class_width_mm``."""
        if not (0 < mean_length_mm <= 500 and 0 <= length_cv <= 1.5):
            raise ConfigError(f"mean length {mean_length_mm} mm / CV {length_cv}: must be in "
                              "(0, 500] mm and [0, 1.5]", source=f"staple diagram '{name}'")  # fmt: skip
        if length_cv == 0:
            return cls(np.array([mean_length_mm]), np.array([1.0]), min(class_width_mm,
                       mean_length_mm), fineness_dtex, fineness_cv, name)  # fmt: skip
        shape = 1.0 / length_cv**2
        dist = stats.gamma(shape, scale=mean_length_mm / shape)
        top = float(dist.ppf(1 - 1e-6))
        edges = np.arange(0.0, top + class_width_mm, class_width_mm)
        weights = np.diff(dist.cdf(edges))
        centres = 0.5 * (edges[1:] + edges[:-1])
        keep = weights > 0
        return cls(centres[keep], weights[keep], class_width_mm, fineness_dtex, fineness_cv, name)

    @classmethod
    def preset(cls, name: str) -> StapleDiagram:
        """Built-in materials (research/sliver.md section 2):

        * ``cotton``: number-mean length 24 mm, CV 33 % (gamma), 1.6 dtex (Micronaire about
          4.1), fineness CV 25 % (assumption, within the 20-35 % of cotton fibres);
        * ``polyester``: 38 mm cut staple, length CV 5 % (cutting spread, assumption),
          1.4 dtex, fineness CV 8 % (assumption).
        """
        if name == "cotton":
            return cls.gamma(24.0, 0.33, 1.6, 0.25, name="cotton")
        if name == "polyester":
            return cls.gamma(38.0, 0.05, 1.4, 0.08, name="polyester")
        raise ConfigError(f"unknown staple preset '{name}'", where="--staple",
                          fix="use cotton, polyester, or a CSV file with columns length_mm, "
                          "fraction")  # fmt: skip

    @classmethod
    def from_table(cls, path: str | Path, fineness_dtex: float,
                   fineness_cv: float = 0.0) -> StapleDiagram:  # fmt: skip
        """Read a staple diagram from CSV (or Parquet): columns ``length_mm`` (class centres,
        equally spaced) and ``fraction`` (number fraction; any scale, normalised here). The
        file goes through the data layer's checks (empty, binary or damaged files are refused
        in one line naming ``--staple``)."""
        import pandas as pd

        from drafttwin.data.io import read_table

        path = Path(path)
        frame = read_table(path, option="--staple")
        for col in ("length_mm", "fraction"):
            if col not in frame.columns:
                raise DataError(f"no column '{col}' (columns: {', '.join(map(str, frame.columns))})",
                                source=path, where="--staple",
                                fix="give columns length_mm and fraction")  # fmt: skip
        lengths = pd.to_numeric(frame["length_mm"], errors="coerce").to_numpy(np.float64)
        weights = pd.to_numeric(frame["fraction"], errors="coerce").to_numpy(np.float64)
        if not (np.all(np.isfinite(lengths)) and np.all(np.isfinite(weights))):
            raise DataError("non-numeric or empty cells", source=path, where="--staple",
                            fix="give numbers in every row")  # fmt: skip
        order = np.argsort(lengths)
        lengths, weights = lengths[order], weights[order]
        steps = np.diff(lengths)
        width = float(steps.min()) if steps.size else min(1.0, float(lengths[0]))
        if steps.size and (width <= 0 or not np.allclose(steps, width, rtol=1e-6)):
            raise DataError("length classes must be equally spaced and distinct",
                            source=path, where="--staple", fix="one row per class")  # fmt: skip
        try:
            return cls(lengths, weights, width, fineness_dtex, fineness_cv, name=path.stem)
        except ConfigError as exc:
            raise DataError(exc.message, source=path, where="--staple") from None

    # ---- moments ------------------------------------------------------------------------
    def moment(self, k: int) -> float:
        """``E[l^k]`` over the number distribution, mm^k (uniform spread within classes)."""
        if k not in self._moments:
            h = self.class_width_mm / 2
            lo, hi = self.lengths_mm - h, self.lengths_mm + h
            per_class = (hi ** (k + 1) - lo ** (k + 1)) / ((k + 1) * 2 * h)
            self._moments[k] = float(np.dot(self.weights, per_class))
        return self._moments[k]

    @property
    def mean_length_mm(self) -> float:
        """Number-mean fibre length E[l], mm."""
        return self.moment(1)

    @property
    def mass_mean_length_mm(self) -> float:
        """Mass-weighted (weight-biased) mean length E[l^2]/E[l], mm."""
        return self.moment(2) / self.moment(1)

    @property
    def fibre_tex(self) -> float:
        """Mean linear density of one fibre, tex (g/km)."""
        return self.fineness_dtex / 10.0

    def fibres_in_cross_section(self, count_ktex: float) -> float:
        """Mean number of fibres in a cross-section of a sliver of ``count_ktex``."""
        return count_ktex * 1000.0 / self.fibre_tex

    def martindale_cv_pct(self, count_ktex: float) -> float:
        """Martindale's limit CV, %, of a random sliver of ``count_ktex`` from these fibres:
        ``100 / sqrt(n) * sqrt(1 + CV_tex^2)`` (the length distribution does not enter)."""
        n = self.fibres_in_cross_section(count_ktex)
        return 100.0 / math.sqrt(n) * math.sqrt(1.0 + self.fineness_cv**2)

    def length_quantiles(self, size: int = 4096) -> np.ndarray:
        """Inverse CDF of the length (mm) at ``size + 1`` equally spaced probabilities 0..1,
        linear within classes: the table the simulator draws lengths from."""
        h = self.class_width_mm / 2
        cdf = np.concatenate([[0.0], np.cumsum(self.weights)])
        edges = np.concatenate([self.lengths_mm - h, [self.lengths_mm[-1] + h]])
        cdf[-1] = 1.0
        p = np.linspace(0.0, 1.0, size + 1)
        quantiles: np.ndarray = np.interp(p, cdf, edges)
        return quantiles

    def fineness_quantiles(self, size: int = 4096) -> np.ndarray:
        """Inverse CDF of one fibre's linear density (tex) at ``size + 1`` midpoint
        probabilities (gamma distribution of mean ``fibre_tex`` and CV ``fineness_cv``)."""
        p = (np.arange(size + 1) + 0.5) / (size + 1)
        if self.fineness_cv == 0:
            return np.full(size + 1, self.fibre_tex)
        shape = 1.0 / self.fineness_cv**2
        q = stats.gamma(shape, scale=self.fibre_tex / shape).ppf(p)
        scaled: np.ndarray = q * (self.fibre_tex / q.mean())  # the table's own mean is the fibre's
        return scaled

    def describe(self) -> dict[str, float | str]:
        return {
            "name": self.name,
            "mean_length_mm": self.mean_length_mm,
            "length_cv": math.sqrt(max(self.moment(2) / self.moment(1) ** 2 - 1.0, 0.0)),
            "mass_mean_length_mm": self.mass_mean_length_mm,
            "fineness_dtex": self.fineness_dtex,
            "fineness_cv": self.fineness_cv,
        }

    @classmethod
    def from_description(cls, described: dict[str, Any]) -> StapleDiagram:
        """The fibres a :meth:`describe` dict names (a record's sidecar): the preset of that
        name with the described fineness when its lengths match the preset's, else a gamma
        length distribution of the described mean and CV. Raises ConfigError or KeyError,
        TypeError, ValueError on a dict that does not describe fibres."""
        mean, cv = float(described["mean_length_mm"]), float(described["length_cv"])
        dtex, dtex_cv = float(described["fineness_dtex"]), float(described["fineness_cv"])
        name = str(described.get("name", "fibres"))
        if name in PRESETS:
            preset = cls.preset(name)
            if math.isclose(preset.mean_length_mm, mean, rel_tol=1e-6):
                return cls(preset.lengths_mm, preset.weights, preset.class_width_mm, dtex,
                           dtex_cv, name)  # fmt: skip
        return cls.gamma(mean, cv, dtex, dtex_cv, name=name)


PRESETS = ("cotton", "polyester")
"""The staple presets (:meth:`StapleDiagram.preset`)."""


@dataclass(frozen=True)
class Fibres:
    """The fibres a sliver record is read with, and where they came from.

    Attributes:
        staple: the staple diagram (Martindale's limit, the ideal curve, the fibre filter).
        source: ``options`` (``--staple`` / ``--fineness-dtex``), ``record`` (the record's
            sidecar names the fibres it was made of) or ``assumed`` (neither: the cotton
            preset, which the report says).
    """

    staple: StapleDiagram
    source: str

    def to_dict(self, count_ktex: float | None = None) -> dict[str, object]:
        out: dict[str, object] = {**self.staple.describe(), "source": self.source}
        if count_ktex is not None:
            out["fibres_in_cross_section"] = self.staple.fibres_in_cross_section(count_ktex)
            out["martindale_cv_pct"] = self.staple.martindale_cv_pct(count_ktex)
        return out

    def note(self) -> str:
        """One line for a report: which fibres, and (when assumed) how to give the real ones."""
        s = self.staple
        what = (f"{s.name}, number-mean length {s.mean_length_mm:.1f} mm, {s.fineness_dtex:.2f} "
                f"dtex (CV {100 * s.fineness_cv:.0f} %)")  # fmt: skip
        if self.source == "assumed":
            return (f"fibres assumed: {what}; the record names none, and Martindale's limit, the "
                    "index of irregularity and the ideal curve follow this assumption (give "
                    "--staple and --fineness-dtex for the record's fibres)")  # fmt: skip
        return f"fibres ({'from the record' if self.source == 'record' else 'as given'}): {what}"


def resolve_fibres(given: StapleDiagram | None, described: object = None) -> Fibres:
    """The fibres to read a record with: ``given`` (options) first, else those the record's
    sidecar ``described`` (a :meth:`StapleDiagram.describe` dict), else the cotton preset,
    marked as assumed."""
    if given is not None:
        return Fibres(given, "options")
    if isinstance(described, dict):
        try:
            return Fibres(StapleDiagram.from_description(described), "record")
        except (KeyError, TypeError, ValueError, ConfigError):
            pass  # a sidecar that does not describe fibres names none
    return Fibres(StapleDiagram.preset("cotton"), "assumed")
