"""Each gear's own run-out (issue 39, item 4): drawn from the law of eccentricity, not set to
ISO 1328's allowable value.

ISO 1328 states the ALLOWABLE radial run-out ``F_r``; an accepted gear's own lies below it. A
gear's eccentricity is a 2-D error vector of its bore against its teeth; with normal,
independent components its length follows Rayleigh's law (the "law of eccentricity" of
manufacturing metrology), its angle is the gear's random phase. A process that just holds
the tolerance puts 99.73 % of its gears within it (``C_p = 1``): ``sigma = (F_r / 2) / 3.44``.
With every gear at ``F_r / 2`` (17.5 um, ``gear_runout_law = "allowable"``, the embedded
data set's plant; ``"rayleigh"`` is the default) gears B and C on the front roller's shaft add up to a 14.14-cm chimney on half of
all machines (docs/sliver.md).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats
from typer.testing import CliRunner

from drafttwin.cli import app
from drafttwin.plant import Machine, Plant, PlantConfig
from drafttwin.plant.config import Eccentricity
from drafttwin.plant.sliver_channel import SliverSettings
from drafttwin.sliver.spectra import spectrogram
from drafttwin.sliver.transfer import fibre_length_gain, roller_gains, transit_lengths_m
from tests.sliver.test_healthy_line import GAUGES, _line

ALLOWABLE = PlantConfig(eccentricity=Eccentricity(gear_runout_law="allowable"))
RAYLEIGH = PlantConfig(eccentricity=Eccentricity(gear_runout_law="rayleigh"))


def _gears(machine: Machine) -> list[dict]:
    return machine.train.to_dict()["gear"]


def _eccentricities_um(config: PlantConfig, seeds: range) -> np.ndarray:
    train = Plant().train
    return np.array([g[f"{side}_eccentricity_um"]
                     for s in seeds for g in _gears(Machine.draw(train, config, s))
                     for side in ("driver", "driven")])  # fmt: skip


def test_gear_eccentricities_follow_rayleighs_law_within_the_tolerance() -> None:
    e = _eccentricities_um(RAYLEIGH, range(300))  # 3000 gears
    half_fr = 0.5 * Eccentricity().gear_runout_um
    sigma = half_fr / math.sqrt(-2.0 * math.log(1.0 - 0.9973))
    assert sigma == pytest.approx(5.09, abs=0.01)
    # the law as a whole, its mean and the share within the tolerance (99.73 %: 8 of 3000 out)
    assert stats.kstest(e, stats.rayleigh(scale=sigma).cdf).pvalue > 0.01
    assert e.mean() == pytest.approx(sigma * math.sqrt(math.pi / 2), rel=0.03)
    assert np.mean(e <= half_fr) == pytest.approx(0.9973, abs=0.003)
    assert np.median(e) < 0.4 * half_fr


def test_the_law_changes_the_run_outs_and_nothing_else_of_the_machine() -> None:
    train = Plant().train
    drawn = Machine.draw(train, RAYLEIGH, 4711)
    at_allowable = Machine.draw(train, ALLOWABLE, 4711)
    assert drawn.draws == at_allowable.draws
    for g, h in zip(_gears(drawn), _gears(at_allowable), strict=True):
        for side in ("driver", "driven"):
            assert g[f"{side}_eccentricity_phase_deg"] == h[f"{side}_eccentricity_phase_deg"]
            assert h[f"{side}_eccentricity_um"] == 17.5
            assert g[f"{side}_eccentricity_um"] < 17.5


def _front_order_line(config: PlantConfig) -> tuple[float, float]:
    """The line (%) the rollers' surfaces leave in the sliver at the front roller's order
    through the drafting transfer (the line a long record converges to: the surfaces' lines
    are kinematic, the sliver's own random irregularity adds a random vector in a short one)
    and the spectrogram's base (%) at 14.14 cm: machine 4711, recording seed 32 (the issue's
    record), 30 s (128 m)."""
    plant = Plant(config=config)
    machine = Machine.draw(plant.train, config, 4711)
    rec = plant.run(30.0, 100.0, seed=32, machine=machine, sliver=SliverSettings())
    s = rec.surface
    v = np.diff(s.length_m, axis=0) / np.diff(s.time_s)[:, None]
    t = 0.5 * (s.time_s[1:] + s.time_s[:-1])
    f_front = v[:, 0].mean() / (2 * math.pi * rec.info["surface"]["radius_m"]["front"])
    lines = np.array([_line(v[:, k] / v[:, k].mean() - 1, t, f_front) for k in range(4)])
    wavelength = v[:, 0].mean() / f_front
    gains = roller_gains(wavelength, transit_lengths_m(GAUGES, rec.sliver.summary["drafts"]))[0]
    true = rec.sliver.true
    line = abs(np.sum(gains * lines) * fibre_length_gain(true.staple, wavelength)[0])
    spec = spectrogram(true.linear_density_ktex, true.step_m, true.staple)
    base = float(spec.base_pct[int(np.argmin(np.abs(spec.wavelength_m - 0.1414)))])
    return 100 * float(line), base


@pytest.mark.slow
def test_the_issues_healthy_machine_has_no_chimney_at_the_front_rollers_order() -> None:
    """The B/2 rule (a channel above 1.5 times its base) asks of a line in a channel of
    random irregularity at the base's level ``sqrt(1.5**2 - 1) = 1.118`` times the base. A
    128-m channel's own scatter moves this machine's channel across the rule from one
    recording to the next (0.21-0.25 % on 0.15-0.17 %), not its line: the line is tested
    (0.159 % against 0.173 %; the whole 513-m record's channel 0.219 % on 0.158 %)."""
    line, base = _front_order_line(RAYLEIGH)
    assert line < 1.118 * base
    # with every gear at its allowable run-out the same record shows it (the issue's chimney)
    line, base = _front_order_line(ALLOWABLE)
    assert line > 1.3 * 1.118 * base  # 0.250 %


def test_generate_takes_the_law_and_records_it(tmp_path: Path) -> None:
    out = tmp_path / "r.csv"
    args = ["generate", "--duration", "0.5", "--machine-seed", "4711", "--out", str(out)]
    res = CliRunner().invoke(app, [*args, "--gear-runout", "rayleigh"])
    assert res.exit_code == 0, res.output
    side = json.loads(out.with_suffix(".json").read_text())
    assert side["plant_config"]["eccentricity"]["gear_runout_law"] == "rayleigh"
    ab = next(g for g in side["true_train"]["gear"] if g["name"] == "A-B")
    assert ab["driven_eccentricity_um"] == pytest.approx(7.0, abs=0.05)  # machine 4711's gear B
    # without the option: the plant's own default law, each gear's own run-out
    plain = tmp_path / "plain.csv"
    res = CliRunner().invoke(app, [*args[:-1], str(plain)])
    assert res.exit_code == 0, res.output
    side = json.loads(plain.with_suffix(".json").read_text())
    assert side["plant_config"]["eccentricity"]["gear_runout_law"] == "rayleigh"
    assert PlantConfig().eccentricity.gear_runout_law == "rayleigh"
    bad = tmp_path / "bad.csv"
    res = CliRunner().invoke(app, [*args[:-1], str(bad), "--gear-runout", "worst"])
    assert res.exit_code == 2
    assert "--gear-runout" in res.output and "allowable or rayleigh" in res.output
    assert not list(tmp_path.glob("bad*"))
