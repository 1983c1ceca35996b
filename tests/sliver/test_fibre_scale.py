"""Lumped fibres (``draft(..., fibre_scale=s)``): each drawn fibre stands for ``s`` fibres, so
the random part's variance grows by ``s`` while the mean count and the deterministic part (a
feed fault's chimney) stay as they are.

Closed forms (research/sliver.md 2, 3.3) for a random sliver of count ``c`` from fibres of
number-mean length ``E[l]`` and fineness CV ``v``:

* point CV of 1 mm bin averages: ``CV_lim(c) * sqrt(s) * sqrt(B(1 mm))``, ``B`` from
  :func:`~drafttwin.sliver.irregularity.variance_length_factor`; for bins shorter than every fibre
  ``B(h) = 1 - h / (3 E[l])`` (number-mean length: 0.98611 for cotton at 1 mm; the
  mass-mean form ``1 - h / (3 E[l^2]/E[l])`` gives 0.98747, 0.07 % apart in CV);
* the relative density's two-sided spectral density at wavelengths far above the fibres,
  ``S = s (CV_lim / 100)^2 E[l^2]/E[l]`` (mm), so the sine and cosine coefficients of a
  chimney fitted over ``L`` mm each scatter by ``sqrt(2 S / L)``.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from drafttwin.sliver import Feed, FeedFault, Sliver, StapleDiagram, draft
from drafttwin.sliver.irregularity import variance_length_factor
from drafttwin.sliver.transfer import fibre_length_gain

from ._speeds import SURFACE_M_S, sine_gain, speeds

COTTON = StapleDiagram.preset("cotton")
FEED = Feed(COTTON, doublings=6, count_ktex=5.5)
RANDOM_M = 60.0  # record of the random slivers, m delivered
FAULT_M = {1: 15.0, 16: 60.0}  # records of the feed-fault runs, m delivered (s = 1 costs most)
LAM_FED_M = 0.1
FAULT = FeedFault(LAM_FED_M, 0.03, "all", "same")


def _duration(length_m: float) -> float:
    return length_m / SURFACE_M_S[0]


def _nominal_count() -> float:
    return FEED.total_ktex / speeds(1.0, rate_hz=1000.0).drafts()["total"]


@functools.cache
def _random_sliver(scale: int) -> Sliver:
    return draft(speeds(_duration(RANDOM_M), rate_hz=1000.0), FEED, seed=21, fibre_scale=scale)


@functools.cache
def _fault_sliver(scale: int) -> Sliver:
    feed = Feed(COTTON, doublings=6, count_ktex=5.5, faults=(FAULT,))
    sp = speeds(_duration(FAULT_M[scale]), rate_hz=1000.0)
    return draft(sp, feed, seed=22, fibre_scale=scale)


def _cv(x: np.ndarray) -> float:
    return float(x.std() / x.mean() * 100)


@pytest.mark.parametrize("scale", [4, 16, 64])
def test_the_random_variance_grows_by_the_fibre_scale(scale):
    """The point CV over sqrt(s) is the full-count CV of a random sliver within 4 % (the
    CV of a 60 m record of 1 mm bins scatters by about 1.2 % (1 sigma): 60000 bins, fibre
    correlation over about 16 mm)."""
    sl = _random_sliver(scale)
    b_1mm = float(variance_length_factor(COTTON, np.array([sl.step_m]))[0])
    assert b_1mm == pytest.approx(1 - 1.0 / (3 * COTTON.mean_length_mm), rel=1e-4)
    full_count_cv = COTTON.martindale_cv_pct(sl.count_ktex) * math.sqrt(b_1mm)
    assert _cv(sl.linear_density_ktex) / math.sqrt(scale) == pytest.approx(full_count_cv, rel=0.04)


@pytest.mark.parametrize("scale", [4, 16, 64])
def test_the_mean_count_does_not_depend_on_the_fibre_scale(scale):
    """Within 0.3 % of the fed count over the draft (the mean of 60 m scatters by
    ``sqrt(S/L)``: 0.1 % at s = 64)."""
    assert _random_sliver(scale).count_ktex == pytest.approx(_nominal_count(), rel=3e-3)


def test_a_feed_faults_chimney_does_not_depend_on_the_fibre_scale():
    """A 3 % fault on all six fed slivers in phase, 0.1 m fed (0.657 m delivered): its complex
    amplitude with s = 16 is that with every fibre (s = 1) within 4 sigma of the difference's
    Monte-Carlo scatter (closed form in the module doc; 4 sigma: a chance of exp(-8) = 3e-4
    that the complex difference of two honest runs exceeds it), and each is 3 % times the fibre
    length gain at 0.657 m within 4 sigma of its own scatter. Both counts agree within 0.3 %."""
    lam = LAM_FED_M * speeds(1.0, rate_hz=1000.0).drafts()["total"]
    density = (COTTON.martindale_cv_pct(_nominal_count()) / 100) ** 2 * COTTON.mass_mean_length_mm
    amp, sigma = {}, {}
    for scale in (1, 16):
        sl = _fault_sliver(scale)
        amp[scale] = sine_gain(sl.linear_density_ktex, sl.delivered_length_m, lam)
        sigma[scale] = math.sqrt(2 * scale * density / (sl.length_m * 1e3))
    expected = FAULT.amplitude * abs(fibre_length_gain(COTTON, lam)[0])
    for scale in (1, 16):
        assert abs(amp[scale]) == pytest.approx(expected, abs=4 * sigma[scale])
    assert abs(amp[16] - amp[1]) < 4 * math.hypot(sigma[1], sigma[16])
    assert _fault_sliver(16).count_ktex == pytest.approx(_fault_sliver(1).count_ktex, rel=3e-3)
