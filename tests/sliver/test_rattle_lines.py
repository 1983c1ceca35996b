"""Gear rattle in the wavelength table: half a mesh's or a chain's tooth frequency.

A lightly loaded mesh with backlash can lose contact once every two teeth of its excitation
(period doubling): the plant's machine 4711 with each gear's own run-out runs its third
roller 1.40 % at 362 Hz, half the rear chain's 725-Hz tooth frequency, and its sliver carries
the line at 1.18 cm (docs/sliver.md). The table names it, its odd orders only (the even ones
are the tooth frequency's own lines).
"""

from __future__ import annotations

import math

import pytest

from drafttwin.mechanics import DriveTrain
from drafttwin.sliver.attribution import attribute
from drafttwin.sliver.diagnose import running_drafts
from drafttwin.sliver.staple import StapleDiagram
from drafttwin.sliver.wavelengths import wavelength_table

GAUGES = (44.0, 40.0, 46.0)


@pytest.fixture(scope="module")
def train() -> DriveTrain:
    return DriveTrain.preset("fa320a")


def test_every_tooth_rate_has_its_rattle_at_half_the_frequency(train: DriveTrain) -> None:
    table = wavelength_table(train)
    by_name = {e.name: e for e in table.elements}
    pairs = [("chain teeth rear_chain", "rattle below rear_chain")]
    pairs += [(f"mesh {g.name}", f"rattle of {g.name}") for g in train.spec.gear]
    for tooth, rattle in pairs:
        t, r = by_name[tooth], by_name[rattle]
        assert r.kind == "rattle"
        assert r.frequency_hz == pytest.approx(t.frequency_hz / 2, rel=1e-12)
        assert r.wavelength_m == pytest.approx(2 * t.wavelength_m, rel=1e-12)
        assert r.rollers == t.rollers
    chain = by_name["chain teeth rear_chain"]
    assert set(chain.rollers) == {"third", "back"}
    assert 2 * chain.wavelength_m == pytest.approx(0.0118, abs=0.0001)
    # at the tooth line itself the rattle's even order is not offered; at 3/2 of it, its third
    near = {(e.name, h) for e, h in table.near(chain.wavelength_m, 0.005, 8)}
    assert ("chain teeth rear_chain", 1) in near
    assert not any(name.startswith("rattle below") for name, _ in near)
    near = {(e.name, h) for e, h in table.near(2 * chain.wavelength_m / 3, 0.005, 8)}
    assert ("rattle below rear_chain", 3) in near


def test_a_chimney_at_half_the_chain_tooth_rate_is_named_rattle(train: DriveTrain) -> None:
    table = wavelength_table(train)
    rattle = next(e for e in table.elements if e.name == "rattle below rear_chain")
    # machine 4711's record: 0.129 % on a base of 0.050 % at the rattle's wavelength
    row = {"wavelength_m": rattle.wavelength_m, "amplitude_pct": 0.129, "base_pct": 0.050}
    (cause,) = attribute([row], table, GAUGES, running_drafts(table, train),
                         StapleDiagram.preset("cotton"))  # fmt: skip
    top = cause.candidates[0]
    assert top.element == "rattle below rear_chain" and top.harmonic == 1 and top.plausible
    assert cause.verdict.startswith("rattle below rear_chain")
    # the speed modulation it needs of the back and third rollers: about what the plant's
    # third roller runs (1.40 %), through the break zone's small gain at 1.18 cm
    assert 1.0 < top.required_modulation_pct < 2.5
    assert math.isfinite(top.gain) and top.gain < 0.15
