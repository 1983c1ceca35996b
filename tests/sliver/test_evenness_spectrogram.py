"""Evenness and spectrogram of a sliver record against the closed forms of research/sliver.md
(T1: Martindale's limit, T2: the ideal spectrum, T3: CV(L), the chimney rule, Parseval) on
random slivers simulated here with NumPy only."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.optimize import minimize_scalar

from drafttwin.errors import DataError
from drafttwin.sliver.irregularity import (
    evenness,
    ideal_variance_length_cv_pct,
    variance_length_curve,
)
from drafttwin.sliver.spectra import (
    channel_of,
    ideal_psd,
    read_tester_spectrogram,
    spectrogram,
)
from drafttwin.sliver.staple import StapleDiagram

STEP = 0.001  # m, the simulated grid
COTTON = StapleDiagram.preset("cotton")
EQUAL = StapleDiagram.gamma(24.0, 0.0, 1.6, 0.25, name="equal")  # one length, 24 mm


def random_sliver(staple: StapleDiagram, n: float, length_m: float, seed: int,
                  step_m: float = STEP, chunk: int = 1_000_000) -> np.ndarray:  # fmt: skip
    """A random sliver of ``n`` fibres in the cross-section, ktex on a grid of ``step_m``.

    Fibre starts are a Poisson process of rate ``n / E[l]`` per metre (from one longest fibre
    before the record, so the record is stationary), lengths from ``staple.length_quantiles()``,
    fineness from ``staple.fineness_quantiles()``. Each fibre puts ``+tex`` at its start and
    ``-tex`` at its end into a difference array by cloud-in-cell; the cumulative sum is then the
    exact mean linear density over each grid step.
    """
    rng = np.random.default_rng(seed)
    lq = staple.length_quantiles() / 1000.0
    p = np.linspace(0.0, 1.0, lq.size)
    tq = staple.fineness_quantiles()
    rate = n / (staple.mean_length_mm / 1000.0)
    lmax = float(lq[-1])
    m = int(round(length_m / step_m))
    diff = np.zeros(m + 2)
    total = int(rng.poisson(rate * (length_m + lmax)))
    for start in range(0, total, chunk):
        k = min(chunk, total - start)
        a = rng.uniform(-lmax, length_m, k)
        b = a + np.interp(rng.random(k), p, lq)
        tex = tq[rng.integers(0, tq.size, k)] / 1000.0  # ktex
        for end, sign in ((a, 1.0), (b, -1.0)):
            x = np.clip(end / step_m, 0.0, m)
            i = x.astype(np.int64)
            frac = x - i
            diff += np.bincount(i, sign * tex * (1.0 - frac), m + 2)
            diff += np.bincount(i + 1, sign * tex * frac, m + 2)
    return np.cumsum(diff)[:m]


def count_for(staple: StapleDiagram, n: float) -> float:
    """Count (ktex) of a sliver of ``n`` fibres in the cross-section."""
    return n * staple.fibre_tex / 1000.0


def sine(length_m: float, wavelength_m: float, amplitude: float) -> np.ndarray:
    """``1 + amplitude * sin(2 pi s / wavelength)`` on the grid."""
    s = np.arange(int(round(length_m / STEP))) * STEP
    return 1.0 + amplitude * np.sin(2 * np.pi * s / wavelength_m + 0.3)


@pytest.fixture(scope="module")
def healthy() -> np.ndarray:
    """50 m of random cotton sliver, 1000 fibres in the cross-section (seed 3)."""
    return random_sliver(COTTON, 1000, 50.0, seed=3)


# ---- T1: Martindale ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("staple", "fineness_cv"),
    [(COTTON, 0.25), (COTTON, 0.0), (EQUAL, 0.25), (EQUAL, 0.0)],
    ids=["cotton-spread", "cotton-even", "equal-spread", "equal-even"],
)
def test_point_cv_is_martindale(staple: StapleDiagram, fineness_cv: float) -> None:
    """T1: the point CV of a random sliver is Martindale's limit (any length distribution);
    the 1 mm bin averaging lowers it by ``sqrt(B(1 mm))`` (0.7 % for cotton), which the
    expectation includes."""
    staple = StapleDiagram(staple.lengths_mm, staple.weights, staple.class_width_mm,
                           staple.fineness_dtex, fineness_cv, staple.name)  # fmt: skip
    n = 1000
    rho = random_sliver(staple, n, 100.0, seed=11)
    result = evenness(rho, STEP, staple)
    martindale = 100.0 / math.sqrt(n) * math.sqrt(1.0 + fineness_cv**2)
    assert result.martindale_cv_pct == pytest.approx(martindale, rel=0.005)  # count from record
    expected = ideal_variance_length_cv_pct(staple, result.count_ktex, np.array([STEP]))[0]
    assert expected / result.martindale_cv_pct == pytest.approx(1.0, abs=0.01)
    assert result.cv_pct == pytest.approx(expected, rel=0.03)
    assert result.cv_pct == pytest.approx(martindale, rel=0.03)
    assert result.index_of_irregularity == pytest.approx(1.0, abs=0.03)
    assert result.count_ktex == pytest.approx(count_for(staple, n), rel=0.005)
    assert result.u_pct == pytest.approx(result.cv_pct * math.sqrt(2 / math.pi), rel=0.03)
    assert result.length_m == pytest.approx(100.0)


def test_evenness_cuts_and_fibre_scale(healthy: np.ndarray) -> None:
    """Cut CVs follow CV(L); 5 m pieces on 50 m leave 10 pieces, 1 cm on a coarse grid none;
    lumping fibres raises the limit by sqrt(fibre_scale)."""
    result = evenness(healthy, STEP, COTTON)
    ideal = ideal_variance_length_cv_pct(COTTON, result.count_ktex, np.array([0.01]))[0]
    assert result.cv_cut_pct["1 cm"] == pytest.approx(ideal, rel=0.03)
    assert math.isfinite(result.cv_cut_pct["5 m"])
    short = evenness(healthy[:4000], STEP)
    assert math.isnan(short.cv_cut_pct["1 m"]) and short.martindale_cv_pct is None
    coarse = evenness(healthy[::25], 0.025)
    assert math.isnan(coarse.cv_cut_pct["1 cm"])
    scaled = evenness(healthy, STEP, COTTON, fibre_scale=4.0)
    assert scaled.martindale_cv_pct == pytest.approx(2.0 * result.martindale_cv_pct)
    assert set(result.to_dict()) >= {"count_ktex", "cv_pct", "u_pct", "cv_cut_pct"}


@pytest.mark.parametrize(
    ("record", "words"),
    [(np.ones(99), "at least 100"), (np.r_[np.ones(200), np.nan], "non-finite"),
     (np.r_[np.ones(200), -np.ones(300)], "mean")],
)  # fmt: skip
def test_bad_records_are_refused(record: np.ndarray, words: str) -> None:
    with pytest.raises(DataError, match=words) as info:
        evenness(record, STEP)
    assert info.value.where == "--data"
    with pytest.raises(DataError):
        spectrogram(record, STEP)


# ---- Parseval and a pure sinusoid -------------------------------------------------------------
def test_parseval_on_random_sliver(healthy: np.ndarray) -> None:
    result = spectrogram(healthy, STEP, COTTON)
    assert result.all_band_variance.sum() == pytest.approx(result.total_variance, rel=1e-10)
    assert result.total_variance == pytest.approx(np.var(healthy / healthy.mean()), rel=1e-10)
    assert result.all_wavelength_m[0] == pytest.approx(2 * STEP, rel=0.04)
    assert result.all_wavelength_m[-1] == pytest.approx(50.0, rel=0.04)
    odd = spectrogram(healthy[:-1], STEP)  # odd N: no lone Nyquist bin
    assert odd.all_band_variance.sum() == pytest.approx(odd.total_variance, rel=1e-10)


def test_pure_sinusoid_is_one_channel() -> None:
    """1 % at 20 cm on 100 m (500 whole periods): 1.00 % in its channel, nothing elsewhere."""
    result = spectrogram(5.0 * sine(100.0, 0.2, 0.01), STEP)
    at = int(np.argmin(np.abs(np.log(result.wavelength_m / 0.2))))
    assert result.amplitude_pct[at] == pytest.approx(1.0, abs=0.02)
    assert np.delete(result.amplitude_pct, at).max() < 0.05
    assert result.all_band_variance.sum() == pytest.approx(result.total_variance, rel=1e-10)
    assert result.wavelength_m[0] == pytest.approx(0.01) and result.wavelength_m[-1] <= 100 / 6


# ---- T2: ideal spectrum -----------------------------------------------------------------------
def peak_wavelength_m(staple: StapleDiagram) -> float:
    """Wavelength of the maximum of ``P(lambda) = f S(f)`` (per ln lambda), m: a 0.1 %
    log grid, then a bounded search around its best point."""
    f = np.geomspace(1.0, 500.0, 6_000)
    best = float(np.log(f[np.argmax(f * ideal_psd(staple, 5.0, f))]))

    def minus_p(log_f: float) -> float:
        x = np.array([math.exp(log_f)])
        return -float(x[0] * ideal_psd(staple, 5.0, x)[0])

    found = minimize_scalar(minus_p, bounds=(best - 0.002, best + 0.002), method="bounded",
                            options={"xatol": 1e-7})  # fmt: skip
    return float(math.exp(-found.x))


def test_ideal_peak_positions() -> None:
    """T2: the ideal log-wavelength spectrum peaks at 2.69 l (equal lengths) and about 3.1 x
    the number mean (cotton, CV 33 %)."""
    assert peak_wavelength_m(EQUAL) / 0.024 == pytest.approx(2.69, rel=0.02)
    cotton = peak_wavelength_m(COTTON) / (COTTON.mean_length_mm / 1000.0)
    assert cotton == pytest.approx(3.1, rel=0.05)
    assert peak_wavelength_m(COTTON) / (COTTON.mass_mean_length_mm / 1000.0) == pytest.approx(
        2.85, rel=0.02
    )


def test_ideal_psd_integrates_to_martindale() -> None:
    f = np.geomspace(1e-4, 1e6, 40_001)  # the tails outside hold about 1e-5 of it
    total = np.trapezoid(ideal_psd(COTTON, 5.0, f), f)
    assert total == pytest.approx((COTTON.martindale_cv_pct(5.0) / 100) ** 2, rel=2e-4)


def test_random_sliver_follows_ideal_spectrum() -> None:
    """T2: band variances of a 100 m random sliver over the significant channels (1 cm to 4 m):
    mean ratio to the ideal within 5 %, power sum within 3 Monte-Carlo standard deviations.
    The ideal band variance is scaled by each band's bin coverage (a band near 25 periods holds
    1-2 periodogram bins for 1.7 bins' width)."""
    rho = random_sliver(COTTON, 1000, 100.0, seed=5)
    result = spectrogram(rho, STEP, COTTON)
    sig = result.significant
    assert result.ideal_pct is not None and sig.sum() > 80
    measured = (result.amplitude_pct[sig] / 100) ** 2 / 2
    expected = (result.ideal_pct[sig] / 100) ** 2 / 2 * result.coverage[sig]
    assert np.mean(measured / expected) == pytest.approx(1.0, abs=0.05)
    spread = np.sqrt(np.sum(expected**2 / result.bins[sig]))  # var of chi2(2m)/(2m) is 1/m
    assert abs(measured.sum() - expected.sum()) < 3 * spread
    assert result.chimneys() == []


# ---- T3: variance-length curve ----------------------------------------------------------------
def test_variance_length_curve_follows_closed_form() -> None:
    """T3: CV(L) of 1 km of random sliver (n = 300) within 5 % of the closed form at 1 cm to 1 m
    (1000 pieces of 1 m: about 2 % standard error)."""
    rho = random_sliver(COTTON, 300, 1000.0, seed=7)
    lengths, cv = variance_length_curve(rho, STEP, np.array([0.01, 0.03, 0.1, 0.3, 1.0]))
    ideal = ideal_variance_length_cv_pct(COTTON, float(rho.mean()), lengths)
    np.testing.assert_allclose(cv / ideal, 1.0, atol=0.05)
    default_l, default_cv = variance_length_curve(rho[:100_000], STEP)
    assert default_l[0] == pytest.approx(2 * STEP) and default_l[-1] == pytest.approx(10.0)
    assert default_l.size <= 30 and np.all(np.diff(default_l) > 0)
    assert np.all(np.isfinite(default_cv))


def test_closed_form_equal_lengths_and_slope() -> None:
    """T3: B(L) = 1 - L/(3l) (L <= l), (l/L)(1 - l/(3L)) (L >= l) for one length; slope -1/2
    and level E[l^2]/(E[l] L) for L >> l."""
    count = 5.0
    limit = EQUAL.martindale_cv_pct(count)
    length = 0.024
    lengths = np.array([0.002, 0.01, 0.024, 0.05, 0.2, 3.0])
    b = np.where(lengths <= length, 1 - lengths / (3 * length),
                 (length / lengths) * (1 - length / (3 * lengths)))  # fmt: skip
    cv = ideal_variance_length_cv_pct(EQUAL, count, lengths)
    np.testing.assert_allclose((cv / limit) ** 2, b, rtol=1e-4)
    far = np.array([5.0, 10.0])
    cv_far = ideal_variance_length_cv_pct(COTTON, count, far)
    assert np.log(cv_far[1] / cv_far[0]) / np.log(2.0) == pytest.approx(-0.5, abs=0.002)
    level = COTTON.moment(2) / COTTON.moment(1) / 1000.0 / far[1]
    assert (cv_far[1] / COTTON.martindale_cv_pct(count)) ** 2 == pytest.approx(level, rel=0.01)


# ---- chimney rule -----------------------------------------------------------------------------
def test_chimney_at_14_cm_and_none_without(healthy: np.ndarray) -> None:
    clean = spectrogram(healthy, STEP, COTTON)
    assert clean.chimneys() == []
    faulty = spectrogram(healthy * sine(50.0, 0.14, 0.015), STEP, COTTON)
    found = faulty.chimneys()
    assert len(found) == 1
    assert channel_of(np.array([found[0]["wavelength_m"]]))[0] == channel_of(np.array([0.14]))[0]
    # the random part's bin at 14 cm adds coherently to the sine: about +-20 % on the amplitude
    assert found[0]["amplitude_pct"] == pytest.approx(
        math.hypot(1.5, found[0]["ideal_pct"]), rel=0.2
    )


def test_significant_but_below_half_base_is_no_chimney(healthy: np.ndarray) -> None:
    """A 0.4 % sine at 3 cm (114 bins in its band) is far beyond chance (p < 1e-6) but rises
    less than half the base above it: the B/2 rule keeps it out."""
    result = spectrogram(healthy * sine(50.0, 0.03, 0.004), STEP, COTTON)
    at = int(np.argmin(np.abs(np.log(result.wavelength_m / 0.03))))
    assert result.p_value[at] < 1e-6
    assert result.base_pct[at] < result.amplitude_pct[at] < 1.5 * result.base_pct[at]
    assert not result.chimney.any()


def test_healthy_slivers_have_no_chimney() -> None:
    """Five seeds, no chimney; the B/2 rule alone would flag some random long-wave channels
    (that is why the chi-square test is there)."""
    b2_only = 0
    for seed in range(10, 15):
        result = spectrogram(random_sliver(COTTON, 1000, 50.0, seed=seed), STEP, COTTON)
        assert not result.chimney.any(), seed
        rule = result.amplitude_pct - result.base_pct > result.base_pct / 2
        b2_only += int((rule & result.significant).sum())
    assert b2_only > 0


# ---- a tester's export ------------------------------------------------------------------------
def write_export(result_frame: pd.DataFrame, path: Path) -> Path:
    """A tester-like CSV: wavelength in cm, amplitude, significance."""
    out = pd.DataFrame({
        "wavelength_cm": result_frame["wavelength_m"] * 100.0,
        "amplitude_pct": result_frame["amplitude_pct"],
        "significant": result_frame["significant"],
    })  # fmt: skip
    out.to_csv(path, index=False)
    return path


def test_read_tester_round_trip(healthy: np.ndarray, tmp_path: Path) -> None:
    faulty = spectrogram(healthy * sine(50.0, 0.14, 0.015), STEP, COTTON)
    frame = faulty.to_frame()
    columns = ["wavelength_m", "lo_m", "hi_m", "amplitude_pct", "ideal_pct", "base_pct",
               "periods", "significant", "chimney", "p_value"]  # fmt: skip
    assert list(frame.columns) == columns
    path = write_export(frame.iloc[::-1], tmp_path / "tester.csv")  # any row order
    plain = read_tester_spectrogram(path)
    np.testing.assert_allclose(plain.wavelength_m, faulty.wavelength_m, rtol=1e-12)
    np.testing.assert_allclose(plain.edges_m, faulty.edges_m, rtol=1e-12)
    np.testing.assert_allclose(plain.amplitude_pct, faulty.amplitude_pct, rtol=1e-12)
    np.testing.assert_array_equal(plain.significant, faulty.significant)
    assert plain.ideal_pct is None and np.all(np.isnan(plain.p_value))
    full = read_tester_spectrogram(path, COTTON, count_ktex=float(healthy.mean()))
    assert full.ideal_pct is not None and faulty.ideal_pct is not None
    grid = np.sinc(1.0 / faulty.wavelength_m * STEP)  # the record's grid factor, absent here
    np.testing.assert_allclose(full.ideal_pct * grid, faulty.ideal_pct, rtol=0.01)
    at = channel_of(full.wavelength_m) == channel_of(np.array([0.14]))[0]
    assert full.chimney[at].all()
    assert [round(row["wavelength_m"], 4) for row in full.chimneys()].count(0.1393) == 1


def test_a_tester_export_counts_periods_from_the_tested_length(
    healthy: np.ndarray, tmp_path: Path
) -> None:
    # an export without significance marks made every channel significant, its longest
    # waves (6-25 periods read) too; with the length the tester read they count as for a
    # record
    faulty = spectrogram(healthy * sine(50.0, 0.14, 0.015), STEP, COTTON)
    frame = faulty.to_frame()
    path = tmp_path / "tester.csv"
    pd.DataFrame({"wavelength_cm": frame["wavelength_m"] * 100.0,
                  "amplitude_pct": frame["amplitude_pct"]}).to_csv(path, index=False)  # fmt: skip
    assert (~faulty.significant).any() and read_tester_spectrogram(path).significant.all()
    read = read_tester_spectrogram(path, tested_length_m=faulty.length_m)
    np.testing.assert_allclose(read.periods, faulty.periods, rtol=1e-12)
    np.testing.assert_array_equal(read.significant, faulty.significant)
    np.testing.assert_array_equal(read.shown_not_significant, faulty.shown_not_significant)
    assert not (read.chimney & ~read.significant).any() and read.length_m == faulty.length_m
    with pytest.raises(DataError) as info:
        read_tester_spectrogram(path, tested_length_m=-1.0)
    assert info.value.where == "--tested-m"


@pytest.mark.parametrize(
    ("text", "column"),
    [("wavelength_m,amp\n0.1,1.0\n", "amplitude_pct"),
     ("lambda,amplitude_pct\n0.1,1.0\n", "wavelength"),
     ("wavelength_cm,amplitude_pct\n10,1.0\n20,abc\n", "amplitude_pct"),
     ("wavelength_mm,amplitude_pct\n100,1.0\nx,1.0\n", "wavelength_mm"),
     ("wavelength_cm,amplitude_pct,significant\n10,1.0,maybe\n", "significant")],
)  # fmt: skip
def test_read_tester_errors(tmp_path: Path, text: str, column: str) -> None:
    path = tmp_path / "export.csv"
    path.write_text(text)
    with pytest.raises(DataError) as info:
        read_tester_spectrogram(path)
    assert info.value.where == "--spectrogram"
    assert str(path) in info.value.message and column in info.value.message
    with pytest.raises(DataError, match="no such file"):
        read_tester_spectrogram(tmp_path / "missing.csv")
