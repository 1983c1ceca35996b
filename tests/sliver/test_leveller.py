"""T10: an open-loop autoleveller (research/sliver.md section 6 and check T10)."""

from __future__ import annotations

import numpy as np
import pytest

from drafttwin.sliver import Feed, StapleDiagram, draft
from drafttwin.sliver.leveller import Autoleveller

from ._speeds import speeds

COTTON = StapleDiagram.preset("cotton")


def _means(sliver, lo_m: float, hi_m: float) -> float:
    s = sliver.delivered_length_m
    return float(sliver.linear_density_ktex[(s >= lo_m) & (s < hi_m)].mean())


def test_a_sliver_running_out_is_levelled_within_the_correction_length():
    """One of six slivers runs out at 1.5 m of fed sliver (9.9 m delivered): without the
    leveller the count falls by 1/6; with it (full intensity, the right action point) the
    count is restored within 1 % once 0.5 m past the step."""
    sp = speeds(8.0, rate_hz=2000.0)
    feed = Feed(COTTON, 6, 5.5, runs_out_m=(1.5, 100.0))
    step_m = 1.5 * sp.drafts()["total"]
    plain = draft(sp, feed, seed=1, fibre_scale=20)
    levelled = draft(sp, feed, seed=1, fibre_scale=20, leveller=Autoleveller())
    before, after = (0.5, step_m - 0.5), (step_m + 0.5, 33.0)
    drop = _means(plain, *after) / _means(plain, *before) - 1
    assert drop == pytest.approx(-1 / 6, abs=0.01)
    assert _means(levelled, *after) == pytest.approx(_means(levelled, *before), rel=0.01)
    assert levelled.info["leveller"]["intensity"] == 1.0


def test_cv_against_the_action_point_is_v_shaped():
    """A fed sliver with 5 % extra irregularity: the levelled CV is lowest at the true action
    point and grows on both sides of it (the tuning run of research/sliver.md section 6)."""
    sp = speeds(8.0, rate_hz=2000.0)
    feed = Feed(COTTON, 1, 33.0, extra_cv=0.05, extra_correlation_m=0.05)
    plain = draft(sp, feed, seed=3, fibre_scale=4).linear_density_ktex
    cv = {}
    for offset in (-30.0, -10.0, 0.0, 10.0, 30.0):
        x = draft(sp, feed, seed=3, fibre_scale=4,
                  leveller=Autoleveller(action_offset_mm=offset)).linear_density_ktex[1000:]  # fmt: skip
        cv[offset] = float(x.std() / x.mean())
    assert min(cv, key=cv.__getitem__) == 0.0
    assert cv[-30.0] > cv[-10.0] > cv[0.0] < cv[10.0] < cv[30.0]
    assert cv[0.0] < 0.5 * float(plain.std() / plain.mean())


def test_the_leveller_refuses_settings_out_of_range():
    from drafttwin.errors import ConfigError

    with pytest.raises(ConfigError, match="--leveller"):
        Autoleveller(intensity=-1.0)
    assert np.isfinite(Autoleveller().sensor_mm)
