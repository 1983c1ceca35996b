"""The drafting simulator against closed forms (research/sliver.md, checks T4-T9).

Fixed seeds; each check states its tolerance. Lumped fibres (``fibre_scale``) keep the runs
short: they raise only the random part, which every tolerance here allows for.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from drafttwin.mechanics import DriveTrain
from drafttwin.sliver import DraftingZones, Feed, FeedFault, RealDrafting, StapleDiagram, draft
from drafttwin.sliver.transfer import fibre_length_gain, mass_gain, transit_lengths_m
from drafttwin.sliver.wavelengths import wavelength_table

from ._speeds import GAUGES_MM, sine_gain, speeds

COTTON = StapleDiagram.preset("cotton")


def _cv(x: np.ndarray) -> float:
    return float(x.std() / x.mean() * 100)


def test_count_is_the_fed_count_times_doublings_over_the_draft():
    sp = speeds(8.0)
    feed = Feed(COTTON, doublings=6, count_ktex=5.5)
    sl = draft(sp, feed, seed=1, fibre_scale=20)
    expected = 6 * 5.5 / sp.drafts()["total"]
    assert sl.count_ktex == pytest.approx(expected, rel=2e-3)


def test_ideal_drafting_of_a_random_feed_is_a_random_sliver():
    """T4: constant speeds; the output's CV is Martindale's limit of the output count
    (bin averaging over 1 mm lowers the variance by B(1 mm) = 1 - 1/(3 E[l]) for cotton)."""
    sp = speeds(60.0, rate_hz=1000.0)
    sl = draft(sp, Feed(COTTON, 6, 5.5), seed=3, fibre_scale=50)
    limit = COTTON.martindale_cv_pct(sl.count_ktex) * math.sqrt(50)
    bin_factor = math.sqrt(1 - 1.0 / (3 * COTTON.mean_length_mm))
    assert _cv(sl.linear_density_ktex) == pytest.approx(limit * bin_factor, rel=0.03)


def test_independent_acceleration_points_add_no_irregularity():
    """T4: a spread of acceleration points that is independent from fibre to fibre leaves a
    random sliver random; only the coupled (correlated) acceleration adds irregularity."""
    sp = speeds(60.0, rate_hz=1000.0)
    feed = Feed(COTTON, 6, 5.5)
    ideal = draft(sp, feed, seed=4, fibre_scale=50)
    spread = draft(sp, feed, seed=4, fibre_scale=50, real=RealDrafting(8.0, coupling=0.0))
    coupled = draft(sp, feed, seed=4, fibre_scale=50, real=RealDrafting(8.0, coupling=3.0))
    cv_i, cv_s, cv_c = (_cv(s.linear_density_ktex) for s in (ideal, spread, coupled))
    assert cv_s == pytest.approx(cv_i, rel=0.03)
    assert cv_c > 1.1 * cv_i


@pytest.mark.parametrize("roller, wavelength", [("front", 0.2), ("front", 0.05), ("back", 0.2)])
def test_a_roller_modulation_leaves_its_chimney_through_the_drafting_transfer(roller, wavelength):
    """T5: a 3 % surface-speed sine (small enough to stay linear; the gain per 1 % is the
    same) on the front roller thins the sliver in antiphase, on the
    back roller thickens it after the zones' transit; amplitude and phase as the complex
    closed form (fibre-length filter included), within 0.06 % (Monte-Carlo scatter)."""
    sp = speeds(12.0, roller, 0.03, wavelength)
    sl = draft(sp, Feed(COTTON, 6, 5.5), seed=50, fibre_scale=5)
    measured = sine_gain(sl.linear_density_ktex, sl.delivered_length_m, wavelength) / 0.03
    predicted = mass_gain({roller: 1.0}, wavelength, GAUGES_MM, sp.drafts(), COTTON)[0]
    assert abs(measured - predicted) < 0.06
    if roller == "front" and wavelength >= 0.2:
        assert abs(predicted) > 0.95 and measured.real < -0.8  # about 1 %, antiphase
    if roller == "back":
        assert abs(measured) > 0.85


def test_a_middle_roller_is_a_comb_filter():
    """T6: the second roller's gain is 2 sin(pi d2 / lambda) H_l: double at lambda = 2 d2,
    null at lambda = d2 (d2 the main zone's gauge times its draft)."""
    d2, _ = transit_lengths_m(GAUGES_MM, speeds(1.0).drafts())
    gains = []
    for lam in (2 * d2, d2):
        sp = speeds(12.0, "second", 0.03, lam)
        sl = draft(sp, Feed(COTTON, 6, 5.5), seed=50, fibre_scale=5)
        gains.append(abs(sine_gain(sl.linear_density_ktex, sl.delivered_length_m, lam)) / 0.03)
    h_l = abs(fibre_length_gain(COTTON, 2 * d2)[0])
    assert gains[0] == pytest.approx(2 * h_l, abs=0.08)
    assert gains[1] < 0.05


def test_doublings_divide_independent_irregularity_by_their_root():
    """T7: k slivers with independent extra irregularity: the added variance falls as 1/k;
    a periodic feed fault in phase on all slivers is not reduced."""
    sp = speeds(12.0)
    added = {}
    for k in (1, 4):
        feed = Feed(COTTON, k, 33.0 / k, extra_cv=0.04, extra_correlation_m=0.05)
        sl = draft(sp, feed, seed=7, fibre_scale=4)
        base = COTTON.martindale_cv_pct(sl.count_ktex) * 2.0  # sqrt(fibre_scale)
        added[k] = math.sqrt(max(_cv(sl.linear_density_ktex) ** 2 - base**2, 0.0))
    ratio = added[4] / added[1]
    assert ratio == pytest.approx(0.5, abs=0.1)
    lam_in = 0.1  # on the fed sliver: 0.657 m delivered
    draft_total = sp.drafts()["total"]
    same = Feed(COTTON, 4, 8.25, faults=(FeedFault(lam_in, 0.02, "all", "same"),))
    sl = draft(sp, same, seed=8, fibre_scale=4)
    amp = abs(sine_gain(sl.linear_density_ktex, sl.delivered_length_m, lam_in * draft_total))
    assert amp == pytest.approx(0.02, rel=0.1)


def test_random_phase_feed_faults_average_down_with_doublings():
    """T7: the same fault on k slivers with random phases: the mean power over seeds is
    1/k of one sliver's (amplitude RMS a / sqrt(k))."""
    sp = speeds(4.0)
    lam_in = 0.1
    powers = []
    for seed in range(20):
        feed = Feed(COTTON, 4, 8.25, faults=(FeedFault(lam_in, 0.02, "all", "random"),))
        sl = draft(sp, feed, seed=100 + seed, fibre_scale=10)
        c = sine_gain(sl.linear_density_ktex, sl.delivered_length_m, lam_in * sp.drafts()["total"])
        powers.append(abs(c) ** 2)
    assert math.sqrt(np.mean(powers)) == pytest.approx(0.02 / 2, rel=0.3)


def test_kinematic_wavelengths_of_the_fa320a():
    """T8: the motor at 1450 rpm and 256 m/min leaves 17.7 cm; a roller its circumference
    times the draft from it to the front."""
    train = DriveTrain.preset("fa320a")
    table = wavelength_table(train, motor_rpm=1450.0)
    by_name = {e.name: e for e in table.elements}
    v = table.delivery_m_min
    assert by_name["motor motor"].wavelength_m == pytest.approx(v / 1450.0, rel=1e-12)
    assert by_name["motor motor"].wavelength_m == pytest.approx(0.177, abs=0.001)
    rpm = {r.name: v / (math.pi * r.diameter_mm * 1e-3) for r in train.spec.roller}
    for r in train.spec.roller:
        roller_rpm = by_name[f"roller {r.name}"].frequency_hz * 60
        d_to_front = v / (roller_rpm * math.pi * r.diameter_mm * 1e-3)
        expected = math.pi * r.diameter_mm * 1e-3 * d_to_front
        assert by_name[f"roller {r.name}"].wavelength_m == pytest.approx(expected, rel=1e-12)
    assert by_name["roller front"].wavelength_m == pytest.approx(math.pi * 0.045, rel=1e-12)
    assert rpm["front"] == pytest.approx(by_name["roller front"].frequency_hz * 60, rel=1e-9)


def test_short_waves_are_buried_by_fibre_overlap_and_reappear_after_a_second_draft():
    """T9: a front-roller modulation at 1.5 cm (shorter than the fibres) is almost invisible
    in the mass, but the fibre ends carry it: a second passage at draft 6.6 stretches it to
    9.9 cm, where the fibres no longer hide it."""
    lam = 0.015
    sp = speeds(4.0, "front", 0.03, lam)
    first = draft(sp, Feed(COTTON, 6, 5.5), seed=9, fibre_scale=20, keep_fibres=10**7)
    seen_first = abs(sine_gain(first.linear_density_ktex, first.delivered_length_m, lam))
    assert seen_first < 0.004  # 3 % of speed, under 0.4 % of mass
    from drafttwin.sliver.drafting import draft_fibres

    second = draft_fibres(first.fibres, speeds(3.5), DraftingZones())
    lam2 = lam * sp.drafts()["total"]
    seen_second = abs(sine_gain(second.linear_density_ktex, second.delivered_length_m, lam2))
    assert seen_second > 5 * seen_first
    expected = 0.03 * abs(fibre_length_gain(COTTON, lam2)[0])  # 2.55 %: the ends carried it
    assert seen_second == pytest.approx(expected, abs=0.004)


def test_same_seed_same_sliver_and_pieces_do_not_matter():
    sp = speeds(3.0)
    feed = Feed(COTTON, 6, 5.5)
    a = draft(sp, feed, seed=11, fibre_scale=30)
    b = draft(sp, feed, seed=11, fibre_scale=30)
    assert np.array_equal(a.linear_density_ktex, b.linear_density_ktex)
    import drafttwin.sliver.drafting as D

    old = D.PIECE_M
    try:
        D.PIECE_M = 0.37
        c = draft(sp, feed, seed=11, fibre_scale=30)
    finally:
        D.PIECE_M = old
    assert np.array_equal(a.linear_density_ktex, c.linear_density_ktex)
