"""The coloured residual model of the calibration (white + OU, by maximum likelihood), its
whitening, and the start-from-rest blocks the fit leaves out."""

import numpy as np
import pytest
from scipy.linalg import cholesky, solve_triangular

from drafttwin.calibration import fit as F
from drafttwin.calibration import identify as I
from drafttwin.calibration import noise as N
from drafttwin.data.series import MeasurementSeries
from drafttwin.plant.effects import ou_process

BLOCK_S = 0.1


def _records(rng, n_records, n, ou_sd, tau, white_sd):
    return [ou_process(rng, n, BLOCK_S, tau, ou_sd) + white_sd * rng.standard_normal(n)
            for _ in range(n_records)]  # fmt: skip


def test_maximum_likelihood_recovers_wander_correlation_and_white_noise():
    rng = np.random.default_rng(11)
    recs = _records(rng, 8, 600, ou_sd=2.0, tau=5.0, white_sd=1.0)
    t = BLOCK_S * np.arange(600)
    noise = N.fit_noise([(t, r) for r in recs], BLOCK_S)
    # eight minutes hold about 48 correlation times: the wander's variance to ~20 %
    assert np.sqrt(noise.ou_var) == pytest.approx(2.0, rel=0.2)
    assert noise.tau_s == pytest.approx(5.0, rel=0.35)
    assert np.sqrt(noise.white_var) == pytest.approx(1.0, rel=0.1)
    # white data: the wander's share vanishes
    white = N.fit_noise([(t, rng.standard_normal(600)) for _ in range(4)], BLOCK_S)
    assert white.ou_var < 0.05 and white.white_var == pytest.approx(1.0, rel=0.1)


def test_innovations_are_the_inverse_cholesky_factor_of_the_covariance_with_gaps():
    rng = np.random.default_rng(10)
    noise = N.ChannelNoise(white_var=0.3, ou_var=2.0, tau_s=1.5)
    t = BLOCK_S * np.r_[np.arange(40), np.arange(47, 90)]  # a gap of 7 blocks
    r = rng.standard_normal(len(t))
    mask = np.zeros((90, 1), bool)
    mask[np.rint(t / BLOCK_S).astype(int), 0] = True
    full = np.full((90, 1), np.nan)
    full[mask[:, 0], 0] = r
    got = N.Whitener([noise], mask, [(0, 90)], BLOCK_S)(full)[mask[:, 0], 0]
    expected = solve_triangular(cholesky(noise.covariance(t), lower=True), r, lower=True)
    np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-12)


def test_whitened_residual_is_white_with_unit_variance_and_gaps_stay_unscored():
    rng = np.random.default_rng(12)
    noise = N.ChannelNoise(white_var=0.25, ou_var=4.0, tau_s=5.0)
    recs = _records(rng, 2, 3000, ou_sd=2.0, tau=5.0, white_sd=0.5)
    r = np.concatenate(recs)[:, None]
    mask = np.ones_like(r, bool)
    mask[100:110] = False  # a gap: not scored, and the covariance skips it
    white = N.Whitener([noise], mask, [(0, 3000), (3000, 6000)], BLOCK_S)(r)[:, 0]
    assert np.isnan(white[100:110]).all()
    w = white[np.isfinite(white)]
    lag1 = lambda v: np.corrcoef(v[1:], v[:-1])[0, 1]  # noqa: E731
    assert lag1(r[:, 0]) > 0.9 and abs(lag1(w)) < 0.05
    assert np.std(w) == pytest.approx(1.0, rel=0.05)


def test_generalised_least_squares_level_has_honest_errors_where_white_ones_are_not():
    """The level of a record under a 5 s wander: over repeated records the spread of the GLS
    level matches its standard error sqrt((1' C^-1 1)^-1); the white-noise formula is several
    times too small, and an AR(1) whitening filter without its first-sample term would
    keep almost nothing of the level (its information ~ n (1 - a)^2 / s2_e)."""
    rng = np.random.default_rng(13)
    noise, n = N.ChannelNoise(white_var=0.04, ou_var=1.0, tau_s=5.0), 600
    mask = np.ones((n, 1), bool)
    whiten = N.Whitener([noise], mask, [(0, n)], BLOCK_S)
    ones = whiten(np.ones((n, 1)))[:, 0]
    se = 1.0 / np.sqrt(ones @ ones)
    levels = []
    for _ in range(300):
        r = _records(rng, 1, n, ou_sd=1.0, tau=5.0, white_sd=0.2)[0]
        levels.append((ones @ whiten(r[:, None])[:, 0]) / (ones @ ones))
    assert np.std(levels) == pytest.approx(se, rel=0.15)
    assert se > 4 * np.sqrt(1.04 / n)  # the white formula's error of the mean


def _series(supply: np.ndarray) -> MeasurementSeries:
    n = len(supply)
    return MeasurementSeries(time_s=np.arange(n) / 100.0, values=np.ones((n, 1)),
                             channels=("front",), inputs={"supply_hz": supply})  # fmt: skip


def test_blocks_at_standstill_and_after_a_start_from_rest_are_not_scored():
    supply = np.r_[np.zeros(105), np.linspace(1.0, 50.0, 895)]  # starts at 1.05 s
    cut = F._breakaway(_series(supply), 10, 100)
    assert np.flatnonzero(cut).tolist() == list(range(16))  # to 1.6 s: 0.5 s from 1.05
    running = F._breakaway(_series(np.full(1000, 50.0)), 10, 100)
    assert not running.any()  # a record that starts running has no start from rest


def test_hc3_errors_follow_the_scatter_of_the_rows_that_carry_the_fit():
    """A slope from 200 rows of which 10 carry it: the noise there is 3 times the rest's. The
    white formula averages the scatter and is too small; HC3 matches the slope's spread over
    repeated draws."""
    rng = np.random.default_rng(14)
    x = np.r_[np.zeros(190), np.linspace(1.0, 2.0, 10)]
    jac = np.column_stack([np.ones(200), x])
    sd = np.r_[np.ones(190), np.full(10, 3.0)]
    slopes, hc3, white = [], [], []
    for _ in range(400):
        y = sd * rng.standard_normal(200)
        coef, *_ = np.linalg.lstsq(jac, y, rcond=None)
        r = y - jac @ coef
        slopes.append(coef[1])
        hc3.append(I.hc3_standard_errors(jac, r)[1])
        white.append(I.standard_errors(jac, r)[1])
    spread = np.std(slopes)
    assert np.sqrt(np.mean(np.square(hc3))) == pytest.approx(spread, rel=0.2)
    assert np.sqrt(np.mean(np.square(white))) < 0.6 * spread


def test_the_wander_model_refuses_records_without_a_motor_speed():
    from drafttwin.calibration import calibrate
    from drafttwin.errors import DataError
    from drafttwin.mechanics import DriveTrain

    n = 200
    series = MeasurementSeries(time_s=np.arange(n) / 100.0, values=np.full((n, 4), 100.0),
                               inputs={"supply_hz": np.full(n, 50.0)})  # fmt: skip
    with pytest.raises(DataError, match="motor"):
        calibrate(DriveTrain.preset("fa320a"), series, coloured=("motor",))


def test_offset_error_of_several_records_is_the_dense_gls_one():
    """The level shared by two records (one with a gap) is known to (sum 1' C_r^-1 1)^-1/2,
    C_r each record's dense covariance; the plain mean of a 60 s record is not much worse."""
    noise = N.ChannelNoise(white_var=0.2, ou_var=1.0, tau_s=5.0)
    a = np.arange(0.5, 60.0, BLOCK_S)
    b = np.delete(np.arange(0.0, 40.0, BLOCK_S), np.s_[100:130])
    dense = sum(np.ones(len(t)) @ np.linalg.solve(noise.covariance(t), np.ones(len(t)))
                for t in (a, b))  # fmt: skip
    assert N.offset_sd(noise, [a, b]) == pytest.approx(1.0 / np.sqrt(dense), rel=1e-9)
    assert N.offset_sd(noise, [a]) > N.offset_sd(noise, [a, b])
    assert N.offset_sd(noise, []) == float("inf")


def test_a_records_mean_moves_by_the_ou_formula():
    """Var of a T-mean: the closed form against the block covariance summed (1' C 1 / n^2)
    and against the spread of simulated records' means."""
    noise = N.ChannelNoise(white_var=0.04, ou_var=1.0, tau_s=5.0)
    t = np.arange(0.0, 60.0, BLOCK_S)
    summed = np.sqrt(noise.covariance(t).sum()) / len(t)
    assert N.mean_sd(noise, 60.0, BLOCK_S) == pytest.approx(summed, rel=0.01)
    rng = np.random.default_rng(21)
    means = [r.mean() for r in _records(rng, 400, len(t), ou_sd=1.0, tau=5.0, white_sd=0.2)]
    assert np.std(means) == pytest.approx(N.mean_sd(noise, 60.0, BLOCK_S), rel=0.12)
    assert N.mean_sd(noise, 240.0, BLOCK_S) < 0.55 * N.mean_sd(noise, 60.0, BLOCK_S)
    with pytest.raises(ValueError):
        N.mean_sd(noise, 0.0, BLOCK_S)
