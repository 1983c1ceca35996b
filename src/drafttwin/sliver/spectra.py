"""The 10-per-octave spectrogram of a sliver record, its ideal curve and the chimney rule.

Channels follow the evenness testers (research/sliver.md 3.1): centre wavelengths
``lambda_j = 0.01 m * 2**(j/10)`` (j any integer), band edges at ``lambda_j * 2**(+-1/20)``.
The measured spectrum is the periodogram of the whole mean-removed relative record
``r = rho / mean - 1`` (``np.fft.rfft``, rectangular window), each bin summed into the channel
holding its wavelength ``1/f``; the rectangular window keeps Parseval exact, so the band
variances of all channels from the Nyquist wavelength to the record length add up to
``var(r)``. A channel's amplitude is the equivalent sinusoid, ``100 * sqrt(2 * band variance)`` %.

The ideal curve is the random sliver of research/sliver.md 3.2 (Campbell's theorem):
``S(f) = 2 (1 + CV_tex^2) E[sin^2(pi f l)] / (pi^2 f^2 n E[l])``, one-sided, per unit spatial
frequency ``f`` (1/m), integrated over each band.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import stats

from drafttwin.errors import DataError
from drafttwin.sliver.irregularity import check_record
from drafttwin.sliver.staple import StapleDiagram

if TYPE_CHECKING:
    import pandas as pd

LAMBDA_REF_M = 0.01
"""Reference channel centre (j = 0), m."""

PER_OCTAVE = 10
"""Channels per octave."""

SIGNIFICANT_PERIODS = 25.0
"""Periods a channel needs in the record to count as significant (research/sliver.md 3.1)."""

SHOWN_PERIODS = 6.0
"""Periods a channel needs to be shown at all (as not significant below 25)."""

CHIMNEY_LEVEL = 0.01
"""Family-wise false-alarm level of the chi-square test over the significant channels."""

BASE_HALF_WIDTH = 4
"""Channels either side in the running median that forms the local base."""

POOL_GAP = 2
POOL_REACH = 5
"""The chi-square test's neighbours: channels 2 to 5 away either side (the next channel
left out: a line's leakage reaches it), their variance pooled per periodogram bin."""

BAND_POINTS = 32
"""Quadrature points per band for the ideal curve."""

FRAME_COLUMNS = ("wavelength_m", "lo_m", "hi_m", "amplitude_pct", "ideal_pct", "base_pct",
                 "periods", "significant", "chimney", "p_value")  # fmt: skip


# ---- channels -----------------------------------------------------------------------------
def channel_centre_m(j: np.ndarray | int) -> np.ndarray:
    """Centre wavelength of channel ``j``, m."""
    return LAMBDA_REF_M * 2.0 ** (np.asarray(j, dtype=np.float64) / PER_OCTAVE)


def channel_edges_m(wavelength_m: np.ndarray) -> np.ndarray:
    """Band edges ``(k, 2)`` (short, long), m, of channels centred at ``wavelength_m``."""
    lam = np.asarray(wavelength_m, dtype=np.float64).reshape(-1)
    half = 2.0 ** (1.0 / (2 * PER_OCTAVE))
    return np.stack([lam / half, lam * half], axis=1)


def channel_of(wavelength_m: np.ndarray) -> np.ndarray:
    """Index ``j`` of the channel holding each wavelength (m)."""
    x = PER_OCTAVE * np.log2(np.asarray(wavelength_m, dtype=np.float64) / LAMBDA_REF_M)
    return np.floor(x + 0.5).astype(np.int64)


# ---- the ideal random sliver --------------------------------------------------------------
def _mean_sin2(staple: StapleDiagram, f: np.ndarray) -> np.ndarray:
    """``E[sin^2(pi f l)]`` over the staple diagram, lengths uniform within each class
    (exact: ``(1 - cos(2 pi f c) sinc(f w)) / 2`` for a class of centre c, width w)."""
    c = staple.lengths_mm / 1000.0
    w = staple.class_width_mm / 1000.0
    fc = f.reshape(-1, 1)
    mean_cos = np.cos(2 * np.pi * fc * c) * np.sinc(fc * w)
    mean_sin2: np.ndarray = (0.5 * (1.0 - mean_cos)) @ staple.weights
    return mean_sin2


def ideal_psd(staple: StapleDiagram, count_ktex: float, f_per_m: np.ndarray,
              fibre_scale: float = 1.0, step_m: float = 0.0,
              sensor_length_m: float = 0.0) -> np.ndarray:  # fmt: skip
    """One-sided relative PSD of a random sliver per unit spatial frequency, 1/(1/m) = m:
    ``S(f) = 2 (1+CV_tex^2) E[sin^2(pi f l)] / (pi^2 f^2 n E[l])``, ``n`` the fibres in the
    cross-section divided by ``fibre_scale``, times ``sinc^2(f step_m)`` (a record of bin
    averages) and ``sinc^2(f sensor_length_m)`` (a boxcar sensor). ``f_per_m`` > 0, any shape;
    ``int_0^inf S df = CV_lim^2`` (as a fraction) when both factors are off."""
    f = np.asarray(f_per_m, dtype=np.float64)
    n = staple.fibres_in_cross_section(count_ktex) / fibre_scale
    mean_l = staple.mean_length_mm / 1000.0
    flat = f.reshape(-1)
    s = 2.0 * (1.0 + staple.fineness_cv**2) * _mean_sin2(staple, flat)
    s = s / (np.pi**2 * flat**2 * n * mean_l)
    s = s * np.sinc(flat * step_m) ** 2 * np.sinc(flat * sensor_length_m) ** 2
    return s.reshape(f.shape)


def ideal_band_variance(staple: StapleDiagram, count_ktex: float, edges_m: np.ndarray,
                        fibre_scale: float = 1.0, step_m: float = 0.0,
                        sensor_length_m: float = 0.0) -> np.ndarray:  # fmt: skip
    """Variance (relative, a fraction squared) of the ideal random sliver in each band
    ``edges_m`` ``(k, 2)`` (m): ``int S df`` over ``1/hi .. 1/lo``, trapezoid on 32 log-spaced
    frequencies per band (relative error about 1e-4 on these 7 % wide bands)."""
    edges = np.asarray(edges_m, dtype=np.float64).reshape(-1, 2)
    if edges.shape[0] == 0:
        return np.zeros(0)
    t = np.linspace(0.0, 1.0, BAND_POINTS)
    f_lo, f_hi = 1.0 / edges[:, 1], 1.0 / edges[:, 0]
    f = f_lo[:, None] * (f_hi / f_lo)[:, None] ** t[None, :]
    s = ideal_psd(staple, count_ktex, f, fibre_scale, step_m, sensor_length_m)
    return np.asarray(np.trapezoid(s, f, axis=1), dtype=np.float64)


def ideal_band_amplitude_pct(staple: StapleDiagram, count_ktex: float, wavelengths_m: np.ndarray,
                             fibre_scale: float = 1.0, step_m: float = 0.0,
                             sensor_length_m: float = 0.0) -> np.ndarray:  # fmt: skip
    """Ideal spectrogram amplitude, %, ``100 sqrt(2 band variance)``, of a random sliver of
    ``count_ktex`` at channels centred on ``wavelengths_m`` (m; 10-per-octave bands around each
    centre). ``step_m`` (grid of bin averages) and ``sensor_length_m`` (boxcar sensor) are
    optional low-pass factors, m; 0 leaves them out."""
    edges = channel_edges_m(wavelengths_m)
    var = ideal_band_variance(staple, count_ktex, edges, fibre_scale, step_m, sensor_length_m)
    return 100.0 * np.sqrt(2.0 * var)


# ---- the result ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Spectrogram:
    """A 10-per-octave spectrogram of one sliver record (or a tester's export).

    Attributes:
        wavelength_m: channel centres shown, m: from 1 cm (or the first channel above 2.5 grid
            steps on a coarser grid) up to a sixth of the record.
        edges_m: band edges ``(k, 2)`` (short, long), m.
        amplitude_pct: measured amplitude per channel, ``100 sqrt(2 band variance)`` of
            ``r = rho/mean - 1``, %.
        ideal_pct: the ideal random sliver's amplitude, %, or None without a staple diagram.
        base_pct: local base, %: the larger of the ideal curve and the running median of the
            measured amplitudes over +-4 channels, the channel itself left out. A real sliver
            lies above the ideal curve everywhere (drafting hill, feed irregularity), so the
            chimney rule is read against the spectrum's own base, as testers' users read it
            (research/sliver.md 4.2); leaving the channel out keeps a chimney from raising
            its own base.
        periods: record length / wavelength (NaN for a tester export).
        significant: at least 25 periods in the record.
        shown_not_significant: 6 to 25 periods.
        chimney: significant, rising above the base by more than half the base
            (``amplitude - base > base / 2``, the B/2 rule) and passing the test of chance
            (``p_value`` below 0.01 / number of significant channels, Bonferroni). The B/2 rule
            alone flags random long-wave channels of a healthy sliver: they hold only a few
            periodogram bins, so their band variance scatters like chi-square with few degrees
            of freedom.
        p_value: chance that a random sliver gives this channel's band variance or more,
            against its neighbours: ``u = var / coverage`` (``coverage`` the fraction of the
            band's frequency width its ``m`` periodogram bins represent, ``m / length`` over
            ``1/lo - 1/hi``) over the bin-weighted mean of ``u`` of the channels 2 to 5 away
            either side is F-distributed with ``2 m`` and ``2 sum(m_j)`` degrees of freedom
            where the spectrum is locally flat: the base's own scatter is in the test (a
            median of a few channels of few bins each lies below their mean, and a base taken
            as exact had made 5-10 % of random 64-m slivers show a chimney against the 1 %
            stated). With the ideal curve, the larger of that and the chi-square p-value of
            ``2 m * var / (var_ideal * coverage)`` (``2 m`` degrees of freedom): a chimney
            stands above both. NaN where the test does not apply (no bins, a tester export).
        bins: periodogram bins in each channel (0 for a tester export).
        length_m: record length, m (NaN for a tester export).
        step_m: grid step, m (NaN for a tester export).
        total_variance: ``var(r)`` (a fraction squared; NaN for a tester export).
        all_wavelength_m: centres of ALL channels from the Nyquist wavelength (2 steps) to the
            record length, m.
        all_band_variance: their band variances; they add up to ``total_variance`` exactly
            (Parseval).
    """

    wavelength_m: np.ndarray
    edges_m: np.ndarray
    amplitude_pct: np.ndarray
    ideal_pct: np.ndarray | None
    base_pct: np.ndarray
    periods: np.ndarray
    significant: np.ndarray
    shown_not_significant: np.ndarray
    chimney: np.ndarray
    p_value: np.ndarray
    bins: np.ndarray
    length_m: float
    step_m: float
    total_variance: float
    all_wavelength_m: np.ndarray
    all_band_variance: np.ndarray

    @property
    def coverage(self) -> np.ndarray:
        """Fraction of each shown band's frequency width that its periodogram bins represent
        (about 1; it scatters where a band holds only a few bins)."""
        width = 1.0 / self.edges_m[:, 0] - 1.0 / self.edges_m[:, 1]
        return np.asarray(self.bins / self.length_m / width, dtype=np.float64)

    def to_frame(self) -> pd.DataFrame:
        """One row per shown channel: ``wavelength_m, lo_m, hi_m, amplitude_pct, ideal_pct,
        base_pct, periods, significant, chimney, p_value`` (ideal NaN without a staple)."""
        import pandas as pd

        ideal = (
            np.full(self.wavelength_m.shape, np.nan) if self.ideal_pct is None else self.ideal_pct
        )
        return pd.DataFrame({
            "wavelength_m": self.wavelength_m,
            "lo_m": self.edges_m[:, 0],
            "hi_m": self.edges_m[:, 1],
            "amplitude_pct": self.amplitude_pct,
            "ideal_pct": ideal,
            "base_pct": self.base_pct,
            "periods": self.periods,
            "significant": self.significant.astype(bool),
            "chimney": self.chimney.astype(bool),
            "p_value": self.p_value,
        })  # fmt: skip

    def chimneys(self) -> list[dict[str, Any]]:
        """The chimney channels as row dicts (columns of :meth:`to_frame`)."""
        frame = self.to_frame()
        return [dict(row) for row in frame[frame["chimney"]].to_dict(orient="records")]


# ---- base and chimney rule ----------------------------------------------------------------
def _running_median_excluding_self(values: np.ndarray, half: int = BASE_HALF_WIDTH) -> np.ndarray:
    """Median of the ``half`` neighbours either side of each value, the value itself excluded
    (fewer at the ends; the value itself when it has no neighbour)."""
    k = values.size
    out = values.astype(np.float64).copy()
    for i in range(k):
        neighbours = np.concatenate([values[max(0, i - half) : i], values[i + 1 : i + 1 + half]])
        if neighbours.size:
            out[i] = float(np.median(neighbours))
    return out


def _base_pct(amplitude_pct: np.ndarray, ideal_pct: np.ndarray | None) -> np.ndarray:
    """The local base: max(ideal, running median of the measured amplitudes)."""
    base = _running_median_excluding_self(amplitude_pct)
    return base if ideal_pct is None else np.maximum(base, ideal_pct)


def _above_half_base(amplitude_pct: np.ndarray, base_pct: np.ndarray) -> np.ndarray:
    """The B/2 rule: the part above the base is more than half the base."""
    return np.asarray((amplitude_pct - base_pct > base_pct / 2) & (base_pct > 0), dtype=bool)


def _p_values(band_var: np.ndarray, bins: np.ndarray, coverage: np.ndarray,
              ideal_pct: np.ndarray | None) -> np.ndarray:  # fmt: skip
    """Chance of each band variance or more on a random sliver (see :class:`Spectrogram`):
    an F-test against the channels :data:`POOL_GAP` to :data:`POOL_REACH` away either side,
    pooled, and where the ideal curve is known, the chi-square test against it too (the
    larger p-value: a chimney stands above both)."""
    p = np.full(band_var.shape, np.nan)
    ok = (bins > 0) & (coverage > 0)
    per_cover = np.where(ok, band_var / np.where(ok, coverage, 1.0), 0.0)
    for i in np.flatnonzero(ok):
        pool = [j for j in range(i - POOL_REACH, i + POOL_REACH + 1)
                if abs(j - i) >= POOL_GAP and 0 <= j < p.size and ok[j]]  # fmt: skip
        weights = bins[pool].astype(np.float64)
        pooled = float(np.dot(weights, per_cover[pool]) / weights.sum()) if pool else 0.0
        if pooled > 0:  # 2 m_i and 2 sum(m_j) degrees of freedom: the base's own scatter too
            p[i] = stats.f.sf(per_cover[i] / pooled, 2 * bins[i], 2 * weights.sum())
        if ideal_pct is not None and ideal_pct[i] > 0:
            expected = (ideal_pct[i] / 100.0) ** 2 / 2.0 * coverage[i]
            dof = 2.0 * bins[i]
            chi = stats.chi2.sf(dof * band_var[i] / expected, dof)
            p[i] = chi if np.isnan(p[i]) else max(p[i], chi)
    return p


# ---- the measured spectrogram -------------------------------------------------------------
def _shown_channels(length_m: float, step_m: float) -> np.ndarray:
    """Channel indices shown: from 1 cm (or the first channel above 2.5 steps) to length/6."""
    j_lo = max(0, math.floor(PER_OCTAVE * math.log2(2.5 * step_m / LAMBDA_REF_M)) + 1)
    j_hi = math.floor(PER_OCTAVE * math.log2(length_m / SHOWN_PERIODS / LAMBDA_REF_M) + 1e-9)
    return np.arange(j_lo, j_hi + 1, dtype=np.int64)


def _periodogram(r: np.ndarray, step_m: float) -> tuple[np.ndarray, np.ndarray]:
    """One-sided power per bin ``k = 1 .. N//2`` of the mean-removed ``r`` and its wavelength
    (m): ``2|X_k|^2/N^2``, the Nyquist bin of an even ``N`` once; sums to ``mean(r^2)``."""
    n = r.size
    power = np.abs(np.fft.rfft(r)[1:]) ** 2 * (2.0 / n**2)
    if n % 2 == 0:
        power[-1] /= 2.0
    k = np.arange(1, power.size + 1, dtype=np.float64)
    return power, n * step_m / k


def spectrogram(linear_density: np.ndarray, step_m: float, staple: StapleDiagram | None = None,
                count_ktex: float | None = None, fibre_scale: float = 1.0,
                sensor_length_m: float = 0.0) -> Spectrogram:  # fmt: skip
    """10-per-octave spectrogram of a sliver record (see :class:`Spectrogram`).

    Args:
        linear_density: values on a uniform delivered-length grid, any unit proportional to
            mass per length (read as ktex for the ideal curve's count).
        step_m: grid step, m.
        staple: the fibres, for the ideal curve; None leaves it out.
        count_ktex: count for the ideal curve, ktex; default the record's mean.
        fibre_scale: fibres lumped into one simulated fibre (the ideal variance grows by it).
        sensor_length_m: boxcar length of the sensor that made the record, m (ideal curve
            only; the record already holds the sensor's averaging).
    """
    rho = check_record(linear_density, step_m)
    mean = float(rho.mean())
    r = rho / mean - 1.0
    r = r - r.mean()
    length = rho.size * step_m
    power, wavelength = _periodogram(r, step_m)
    j_all = channel_of(wavelength)
    j0 = int(j_all.min())
    all_var = np.bincount(j_all - j0, weights=power)
    all_bins = np.bincount(j_all - j0)
    shown = _shown_channels(length, step_m)
    band_var = all_var[shown - j0]
    bins = all_bins[shown - j0]
    lam = channel_centre_m(shown)
    edges = channel_edges_m(lam)
    amplitude = 100.0 * np.sqrt(2.0 * band_var)
    ideal = None
    if staple is not None:
        count = mean if count_ktex is None else count_ktex
        ideal = ideal_band_amplitude_pct(staple, count, lam, fibre_scale, step_m, sensor_length_m)
    base = _base_pct(amplitude, ideal)
    periods = length / lam
    significant = periods >= SIGNIFICANT_PERIODS
    coverage = bins / length / (1.0 / edges[:, 0] - 1.0 / edges[:, 1])
    p = _p_values(band_var, bins, coverage, ideal)
    level = CHIMNEY_LEVEL / max(int(significant.sum()), 1)
    chimney = significant & _above_half_base(amplitude, base) & (np.nan_to_num(p, nan=1.0) < level)
    return Spectrogram(
        wavelength_m=lam,
        edges_m=edges,
        amplitude_pct=amplitude,
        ideal_pct=ideal,
        base_pct=base,
        periods=periods,
        significant=significant,
        shown_not_significant=(periods >= SHOWN_PERIODS) & ~significant,
        chimney=chimney,
        p_value=p,
        bins=bins,
        length_m=length,
        step_m=float(step_m),
        total_variance=float(np.mean(r**2)),
        all_wavelength_m=channel_centre_m(np.arange(j0, j0 + all_var.size)),
        all_band_variance=all_var,
    )


# ---- a tester's export --------------------------------------------------------------------
_WAVELENGTH_COLUMNS = {"wavelength_m": 1.0, "wavelength_cm": 0.01, "wavelength_mm": 0.001}


def _numeric_column(frame: pd.DataFrame, column: str, path: Path) -> np.ndarray:
    """A column as float64, refused (DataError) when a cell is empty or not a number."""
    import pandas as pd

    values: np.ndarray = pd.to_numeric(frame[column], errors="coerce").to_numpy(np.float64)
    bad = ~np.isfinite(values)
    if bad.any():
        row = int(np.argmax(bad))
        raise DataError(f"column '{column}': {int(bad.sum())} empty or non-numeric cells (first "
                        f"in data row {row + 1}: {frame[column].iloc[row]!r})", source=path,
                        where="--spectrogram", fix="give a number in every row")  # fmt: skip
    return values


def _bool_column(frame: pd.DataFrame, column: str, path: Path) -> np.ndarray:
    """A column of true/false marks (bool, 1/0, true/false, yes/no) as bool."""
    words = {"true": True, "false": False, "1": True, "0": False, "yes": True, "no": False,
             "1.0": True, "0.0": False}  # fmt: skip
    text = frame[column].astype(str).str.strip().str.lower()
    unknown = ~text.isin(list(words))
    if unknown.any():
        row = int(np.argmax(unknown.to_numpy()))
        raise DataError(f"column '{column}': {frame[column].iloc[row]!r} in data row {row + 1} "
                        "is not a true/false mark", source=path, where="--spectrogram",
                        fix="write true or false (or 1 / 0)")  # fmt: skip
    return np.array([words[t] for t in text], dtype=bool)


def _read_table(path: Path) -> pd.DataFrame:
    """The table through the data layer's file checks (a binary or damaged file refused
    with one line), read errors as DataError naming ``--spectrogram``."""
    from drafttwin.data.io import read_table

    if not path.is_file():
        raise DataError("no such file", source=path, where="--spectrogram",
                        fix="give the path of the evenness tester's CSV export")  # fmt: skip
    return read_table(path, option="--spectrogram")


def _wavelength_column(frame: pd.DataFrame, path: Path) -> np.ndarray:
    """Wavelengths, m, from the first of wavelength_m / _cm / _mm present."""
    columns = ", ".join(map(str, frame.columns))
    for column, scale in _WAVELENGTH_COLUMNS.items():
        if column in frame.columns:
            lam = _numeric_column(frame, column, path) * scale
            if np.any(lam <= 0):
                raise DataError(f"column '{column}': wavelengths must be > 0", source=path,
                                where="--spectrogram",
                                fix="drop rows with wavelength <= 0")  # fmt: skip
            if np.unique(lam).size != lam.size:
                raise DataError(f"column '{column}': repeated wavelengths", source=path,
                                where="--spectrogram", fix="one row per channel")  # fmt: skip
            return lam
    raise DataError(f"no wavelength column (columns: {columns})", source=path,
                    where="--spectrogram",
                    fix="name one column wavelength_m, wavelength_cm or wavelength_mm")  # fmt: skip


def read_tester_spectrogram(path: str | Path, staple: StapleDiagram | None = None,
                            count_ktex: float | None = None, fibre_scale: float = 1.0,
                            sensor_length_m: float = 0.0,
                            tested_length_m: float | None = None) -> Spectrogram:  # fmt: skip
    """An evenness tester's spectrogram export as a :class:`Spectrogram`.

    The CSV has a wavelength column (``wavelength_m``, ``wavelength_cm`` or ``wavelength_mm``),
    ``amplitude_pct`` and optionally ``significant`` (true/false). Rows are sorted by
    wavelength; band edges follow the 10-per-octave rule around each centre. The ideal curve is
    computed at the tester's centres when both ``staple`` and ``count_ktex`` are given (no grid
    factor; ``sensor_length_m`` as in :func:`spectrogram`), else it is None. The base and the
    B/2 rule are as for a record; the chi-square test is skipped (the export has no
    periodogram bins: ``p_value`` is NaN). With ``tested_length_m`` (the sliver length the
    tester read) a channel is significant with at least :data:`SIGNIFICANT_PERIODS` periods in
    it and shown as not significant with :data:`SHOWN_PERIODS` to 25, as for a record; the
    tester's own significance marks, when present, must agree too. Without either every
    channel counts as significant. Without the length ``periods`` and ``length_m`` are NaN;
    ``step_m`` and ``total_variance`` always are.

    Raises:
        DataError: naming the file, the column and ``--spectrogram`` (missing file or column,
            empty or non-numeric cells, wavelengths <= 0 or repeated, amplitudes < 0).
    """
    path = Path(path)
    frame = _read_table(path)
    lam = _wavelength_column(frame, path)
    if "amplitude_pct" not in frame.columns:
        columns = ", ".join(map(str, frame.columns))
        raise DataError(f"no column 'amplitude_pct' (columns: {columns})",
                        source=path, where="--spectrogram",
                        fix="name the amplitude column amplitude_pct (in %)")  # fmt: skip
    amplitude = _numeric_column(frame, "amplitude_pct", path)
    if np.any(amplitude < 0):
        raise DataError("column 'amplitude_pct': amplitudes must be >= 0", source=path,
                        where="--spectrogram", fix="give amplitudes in % (>= 0)")  # fmt: skip
    if "significant" in frame.columns:
        significant = _bool_column(frame, "significant", path)
    else:
        significant = np.ones(lam.size, dtype=bool)
    order = np.argsort(lam)
    lam, amplitude, significant = lam[order], amplitude[order], significant[order]
    nan = np.full(lam.size, np.nan)
    periods, shown = nan.copy(), np.zeros(lam.size, dtype=bool)
    if tested_length_m is not None:
        if not (math.isfinite(tested_length_m) and tested_length_m > 0):
            raise DataError(f"tested length {tested_length_m} m is not > 0", source=path,
                            where="--tested-m", fix="give the metres the tester read, e.g. 1000")  # fmt: skip
        periods = tested_length_m / lam
        shown = significant & (periods >= SHOWN_PERIODS) & (periods < SIGNIFICANT_PERIODS)
        significant = significant & (periods >= SIGNIFICANT_PERIODS)
    ideal = None
    if staple is not None and count_ktex is not None:
        ideal = ideal_band_amplitude_pct(staple, count_ktex, lam, fibre_scale, 0.0, sensor_length_m)
    base = _base_pct(amplitude, ideal)
    return Spectrogram(
        wavelength_m=lam,
        edges_m=channel_edges_m(lam),
        amplitude_pct=amplitude,
        ideal_pct=ideal,
        base_pct=base,
        periods=periods,
        significant=significant,
        shown_not_significant=shown,
        chimney=significant & _above_half_base(amplitude, base),
        p_value=nan.copy(),
        bins=np.zeros(lam.size, dtype=np.int64),
        length_m=math.nan if tested_length_m is None else float(tested_length_m),
        step_m=math.nan,
        total_variance=math.nan,
        all_wavelength_m=np.zeros(0),
        all_band_variance=np.zeros(0),
    )
