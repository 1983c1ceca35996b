"""What the drawing frame is fed: doubled slivers, their count and their irregularity.

The feed is ``doublings`` slivers of ``count_ktex`` each, made of the fibres of a
:class:`StapleDiagram`. Fibre leading ends form a Poisson process along the feed (a random
sliver, Martindale's model) whose rate may be modulated per sliver by:

* periodic faults of the card or an earlier passage (:class:`FeedFault`: wavelength on the
  fed sliver, relative amplitude, on one sliver or on all with random or equal phases);
* extra random irregularity (``extra_cv``: a Gauss-Markov process along each sliver with
  correlation length ``extra_correlation_m``), the part of a real card sliver's CV above
  Martindale's limit.

:meth:`Feed.intensity` gives the total relative rate on a grid of fed length, which the
drafting simulator turns into fibres by a time change of a unit Poisson process.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from drafttwin.errors import ConfigError
from drafttwin.sliver.staple import StapleDiagram


@dataclass(frozen=True)
class FeedFault:
    """A periodic defect of the fed slivers (e.g. an eccentric card doffer).

    Attributes:
        wavelength_m: its wavelength on the fed sliver, m (on the drawn sliver it is stretched
            by the draft).
        amplitude: relative amplitude of the fed sliver's mass (0.05 = +-5 %).
        slivers: ``"one"`` (the first sliver only) or ``"all"``.
        phase: ``"random"`` (each sliver its own, as cans from different cards) or ``"same"``.
    """

    wavelength_m: float
    amplitude: float
    slivers: str = "one"
    phase: str = "random"

    def __post_init__(self) -> None:
        if not (1e-3 <= self.wavelength_m <= 1e4 and 0 < self.amplitude < 1):
            raise ConfigError(
                f"feed fault wavelength {self.wavelength_m} m, amplitude {self.amplitude}: "
                "the wavelength must be in [0.001, 10000] m and the amplitude in (0, 1)",
                where="--feed-fault", fix="e.g. wavelength=0.8:amplitude=0.05")  # fmt: skip
        if self.slivers not in ("one", "all") or self.phase not in ("random", "same"):
            raise ConfigError(f"feed fault slivers={self.slivers}, phase={self.phase}",
                              where="--feed-fault",
                              fix="slivers=one|all, phase=random|same")  # fmt: skip

    @classmethod
    def parse(cls, text: str) -> FeedFault:
        """``wavelength=0.8:amplitude=0.05[:slivers=all][:phase=same]`` (wavelength in m)."""
        fields: dict[str, str] = {}
        for part in text.split(":"):
            m = re.fullmatch(r"\s*(wavelength|amplitude|slivers|phase)\s*=\s*(\S+)\s*", part)
            if m is None:
                raise ConfigError(f"cannot read '{part}' in '{text}'", where="--feed-fault",
                                  fix="a periodic fault wavelength=M:amplitude=A[:slivers="
                                  "one|all][:phase=random|same], a sliver running out "
                                  "missing=FROM_M-TO_M, or a piecing piecing=AT_M")  # fmt: skip
            fields[m.group(1)] = m.group(2)
        try:
            return cls(float(fields["wavelength"]), float(fields["amplitude"]),
                       fields.get("slivers", "one"), fields.get("phase", "random"))  # fmt: skip
        except KeyError as exc:
            raise ConfigError(f"'{text}' has no {exc.args[0]}", where="--feed-fault",
                              fix="give wavelength=M and amplitude=A") from None  # fmt: skip
        except ValueError:
            raise ConfigError(f"'{text}': wavelength and amplitude must be numbers",
                              where="--feed-fault") from None  # fmt: skip


@dataclass(frozen=True)
class Feed:
    """The slivers fed to the drafting arrangement.

    Attributes:
        staple: the fibres.
        doublings: number of slivers fed side by side.
        count_ktex: linear density of each fed sliver, ktex (g/m).
        faults: periodic feed faults.
        extra_cv: extra random irregularity of each fed sliver (fraction of its mean) above
            the random (Poisson) sliver; 0 = a random sliver at Martindale's limit.
        extra_correlation_m: correlation length of that extra irregularity, m.
    """

    staple: StapleDiagram
    doublings: int = 6
    count_ktex: float = 5.5
    faults: tuple[FeedFault, ...] = field(default_factory=tuple)
    extra_cv: float = 0.0
    extra_correlation_m: float = 1.0
    runs_out_m: tuple[float, float] | None = None
    """One sliver runs out between these fed lengths (m from the record's start): a step of
    ``-1/doublings`` in the fed count (an autoleveller's test, research/sliver.md T10)."""
    piecings_m: tuple[float, ...] = ()
    """Piecings of one fed sliver at these fed lengths (m from the record's start): where a
    can ran out and the next was pieced on, the two ends overlap: that sliver doubled over
    :data:`PIECING_M` (assumption)."""

    def __post_init__(self) -> None:
        if not 1 <= self.doublings <= 16:
            raise ConfigError(f"{self.doublings} doublings", where="--doublings",
                              fix="feed 1 to 16 slivers")  # fmt: skip
        if not 0.05 <= self.count_ktex <= 100:
            raise ConfigError(f"fed sliver count {self.count_ktex} ktex", where="--feed-ktex",
                              fix="give 0.05 to 100 ktex (card sliver: about 4-6)")  # fmt: skip
        if not (0 <= self.extra_cv < 0.5 and 0.01 <= self.extra_correlation_m <= 1e4):
            raise ConfigError(f"extra CV {self.extra_cv} / correlation "
                              f"{self.extra_correlation_m} m", where="--feed-cv",
                              fix="a CV in [0, 0.5) and a correlation length of 0.01-1e4 m")  # fmt: skip

    def events(self) -> list[dict[str, float | str]]:
        """The feed's single events (a sliver running out, piecings), for a sidecar."""
        out: list[dict[str, float | str]] = []
        if self.runs_out_m is not None:
            out.append({"kind": "missing", "from_m": self.runs_out_m[0],
                        "to_m": self.runs_out_m[1]})  # fmt: skip
        out += [{"kind": "piecing", "at_m": at, "length_m": PIECING_M} for at in self.piecings_m]
        return out

    @property
    def total_ktex(self) -> float:
        """Linear density of all fed slivers together, ktex."""
        return self.doublings * self.count_ktex

    def expected_cv_pct(self, draft: float, fibre_scale: float = 1.0) -> float:
        """The delivered sliver's CV (%) that these settings imply under ideal drafting at
        constant speeds: Martindale's limit of the delivered count (times ``sqrt(fibre_scale)``)
        plus each fed sliver's extra irregularity over the doublings and the feed faults'
        variance (in phase: a^2/2; random phases on all slivers: a^2/(2k); on one sliver:
        (a/k)^2/2). Left out: the fibre-length smoothing of the extra irregularity (under 3 %
        of its variance for correlation lengths above 0.1 m delivered)."""
        out_ktex = self.total_ktex / draft
        var = (self.staple.martindale_cv_pct(out_ktex) / 100) ** 2 * fibre_scale
        var += self.extra_cv**2 / self.doublings
        k = self.doublings
        for f in self.faults:
            if f.slivers == "one":
                var += (f.amplitude / k) ** 2 / 2
            else:
                var += f.amplitude**2 / 2 / (1 if f.phase == "same" else k)
        cv_pct: float = 100 * var**0.5
        return cv_pct

    def fibres_per_mm(self) -> float:
        """Mean number of fibre leading ends per mm of fed length (all slivers)."""
        n = self.staple.fibres_in_cross_section(self.total_ktex)
        return n / self.staple.mean_length_mm

    def intensity(self, p0_mm: float, step_mm: float, size: int,
                  rng: np.random.Generator) -> np.ndarray:  # fmt: skip
        """Relative rate of fibre leading ends (mean 1 for an even feed) on the fed-length grid
        ``p0_mm + step_mm * arange(size)``: the mean over the slivers of each sliver's own
        modulation, floored at 5 % (a sliver never vanishes)."""
        p_m = (p0_mm + step_mm * np.arange(size)) * 1e-3
        total = np.zeros(size)
        for j in range(self.doublings):
            m = np.ones(size)
            for f in self.faults:
                if f.slivers == "one" and j > 0:
                    continue
                phase = 0.0 if f.phase == "same" else float(rng.uniform(0, 2 * math.pi))
                m += f.amplitude * np.sin(2 * math.pi * p_m / f.wavelength_m + phase)
            if self.extra_cv > 0:
                m += _gauss_markov(rng, size, step_mm * 1e-3, self.extra_correlation_m,
                                   self.extra_cv)  # fmt: skip
            if j == 0 and self.runs_out_m is not None:
                m[(p_m >= self.runs_out_m[0]) & (p_m < self.runs_out_m[1])] = 0.0
            if j == 0:
                for at in self.piecings_m:
                    m[(p_m >= at) & (p_m < at + PIECING_M)] *= 2.0
            total += m
        return np.maximum(total / self.doublings, 0.05)


class FeedStream:
    """A feed's relative rate generated piece by piece along the fed length (a running
    machine's feed, :mod:`drafttwin.sliver.stream`): the same model as
    :meth:`Feed.intensity` (each sliver's periodic faults at phases drawn once, its extra
    irregularity as one Gauss-Markov process carried from piece to piece, the single events
    at their fed lengths), on the grid ``p0_mm + step_mm * k`` from ``k = 0`` on."""

    def __init__(self, feed: Feed, p0_mm: float, step_mm: float,
                 rng: np.random.Generator) -> None:  # fmt: skip
        self.feed, self.p0_mm, self.step_mm, self.rng = feed, p0_mm, step_mm, rng
        self.k = 0  # grid points generated so far
        self.phases = [[0.0 if f.phase == "same" else float(rng.uniform(0, 2 * math.pi))
                        for f in feed.faults] for _ in range(feed.doublings)]  # fmt: skip
        self._a = math.exp(-step_mm * 1e-3 / feed.extra_correlation_m)
        # each sliver its own generator: the realisation does not depend on the pieces' sizes
        self._rngs = rng.spawn(feed.doublings)
        self._gm = [feed.extra_cv * float(r.standard_normal()) for r in self._rngs]

    def next(self, n: int) -> np.ndarray:
        """The relative rate (mean 1 for an even feed) at the next ``n`` grid points."""
        from scipy.signal import lfilter

        feed = self.feed
        p_m = (self.p0_mm + self.step_mm * np.arange(self.k, self.k + n)) * 1e-3
        self.k += n
        total = np.zeros(n)
        for j in range(feed.doublings):
            m = np.ones(n)
            for f, phase in zip(feed.faults, self.phases[j], strict=True):
                if f.slivers == "one" and j > 0:
                    continue
                m += f.amplitude * np.sin(2 * math.pi * p_m / f.wavelength_m + phase)
            if feed.extra_cv > 0:
                b = feed.extra_cv * math.sqrt(1 - self._a**2)
                y, _ = lfilter([b], [1.0, -self._a], self._rngs[j].standard_normal(n),
                               zi=[self._a * self._gm[j]])  # fmt: skip
                self._gm[j] = float(y[-1])
                m += y
            if j == 0 and feed.runs_out_m is not None:
                m[(p_m >= feed.runs_out_m[0]) & (p_m < feed.runs_out_m[1])] = 0.0
            if j == 0:
                for at in feed.piecings_m:
                    m[(p_m >= at) & (p_m < at + PIECING_M)] *= 2.0
            total += m
        return np.maximum(total / feed.doublings, 0.05)


PIECING_M = 0.15
"""Length of a piecing's overlap on the fed sliver, m (assumption: hand piecings overlap the
two ends by 10-20 cm)."""


def parse_feed_event(text: str) -> tuple[str, tuple[float, ...]] | None:
    """``missing=FROM_M-TO_M`` (one sliver runs out between these fed lengths, m) or
    ``piecing=AT_M`` as ``(kind, numbers)``; None for any other text (a periodic fault)."""
    m = re.fullmatch(r"\s*(missing|piecing)\s*=\s*(\S+)\s*", text)
    if m is None:
        return None
    try:
        numbers = tuple(float(x) for x in m.group(2).split("-"))
    except ValueError:
        numbers = ()
    want = 2 if m.group(1) == "missing" else 1
    if len(numbers) != want or not all(0 <= x <= 1e5 for x in numbers) or (
            want == 2 and numbers[1] <= numbers[0]):  # fmt: skip
        raise ConfigError(f"cannot read '{text}'", where="--feed-fault",
                          fix="missing=FROM_M-TO_M (fed m, from < to) or piecing=AT_M")  # fmt: skip
    return m.group(1), numbers


def _gauss_markov(rng: np.random.Generator, n: int, step_m: float, corr_m: float,
                  sd: float) -> np.ndarray:  # fmt: skip
    """A stationary first-order Gauss-Markov sequence along length (std ``sd``)."""
    from scipy.signal import lfilter

    a = math.exp(-step_m / corr_m)
    eps = rng.standard_normal(n + 1)
    y, _ = lfilter([sd * math.sqrt(1 - a * a)], [1.0, -a], eps[1:], zi=[a * sd * eps[0]])
    return np.asarray(y)
