"""A roller's chimney in the unit a fitter measures: the eccentricity (and TIR) that explains
it, where the verdict gave a speed modulation only (0.097 % says nothing at the machine; a
dial gauge reads 17 um)."""

from __future__ import annotations

import math

import pytest

from drafttwin.mechanics import DriveTrain
from drafttwin.sliver.attribution import attribute, runout_um
from drafttwin.sliver.diagnose import running_drafts
from drafttwin.sliver.staple import StapleDiagram
from drafttwin.sliver.transfer import mass_gain

GAUGES = (44.0, 40.0, 46.0)


@pytest.mark.parametrize("roller", ["front", "second", "third", "back"])
def test_a_rollers_line_reads_as_its_eccentricity(roller: str) -> None:
    """A line of excess m over the base at a roller's own wavelength reads as ``e = m / g r``:
    the radius from the train's own diameter (not the line's), the gain from the drafting
    transfer."""
    from drafttwin.sliver.wavelengths import wavelength_table

    train = DriveTrain.preset("fa320a")
    table = wavelength_table(train)
    drafts = running_drafts(table, train)
    staple = StapleDiagram.preset("cotton")
    line = next(e for e in table.elements if e.name == f"roller {roller}")
    base, excess = 0.05, 0.2
    row = {"wavelength_m": line.wavelength_m, "amplitude_pct": math.hypot(base, excess),
           "base_pct": base}  # fmt: skip
    (cause,) = attribute([row], table, GAUGES, drafts, staple)
    cand = next(c for c in cause.candidates if c.element == f"roller {roller}")
    gain = abs(mass_gain({roller: 1.0}, line.wavelength_m, GAUGES, drafts, staple)[0])
    radius_mm = next(float(r.diameter_mm) for r in train.spec.roller if r.name == roller) / 2
    want = excess / gain / 100 * radius_mm * 1e3
    assert runout_um(cand, drafts) == pytest.approx(want, rel=1e-3)
    if cause.candidates[0] is cand:
        assert f"eccentricity {want:.0f} um (TIR {2 * want:.0f} um)" in cause.verdict


def test_no_eccentricity_for_a_harmonic_or_another_element() -> None:
    from drafttwin.sliver.wavelengths import wavelength_table

    train = DriveTrain.preset("fa320a")
    table = wavelength_table(train)
    drafts = running_drafts(table, train)
    front = next(e for e in table.elements if e.name == "roller front")
    row = {"wavelength_m": front.wavelength_m / 3, "amplitude_pct": 0.3, "base_pct": 0.05}
    (cause,) = attribute([row], table, GAUGES, drafts, StapleDiagram.preset("cotton"))
    for c in cause.candidates:
        if c.harmonic != 1 or c.kind != "roller":
            assert runout_um(c, drafts) is None
    assert "eccentricity" not in cause.verdict or "harmonic 1" in cause.verdict
