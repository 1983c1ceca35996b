"""The localisation's model-mismatch term: a machine whose belt is softer than the nominal
physics says still gets its load fault explained, and a sensor gain stays a sensor gain."""

import numpy as np
import pytest
from scipy.stats import chi2

from drafttwin.diagnosis.locate import (
    SignatureModel,
    creep_mismatch,
    nominal_creep,
    rank_causes,
)
from drafttwin.mechanics import DriveTrain

# healthy level noise of a 30-s post-alarm mean: supply wander common to all five channels,
# independent encoder noise per channel (research/faults.md section 1 sizes)
COV = (1e-4**2 * np.ones((5, 5)) + np.diag([1.5e-5**2] * 5)) / 3
# then the three roller angle lags (mrad; independent of the levels here)
COV = np.block([[COV, np.zeros((5, 3))], [np.zeros((3, 5)), np.diag([0.1**2] * 3)]])


@pytest.fixture(scope="module")
def models() -> tuple[SignatureModel, SignatureModel]:
    nominal = DriveTrain.preset("fa320a")
    raw = nominal.to_dict()
    raw["belt"] = [dict(b, axial_rigidity_n=0.7 * b["axial_rigidity_n"]) for b in raw["belt"]]
    return SignatureModel(nominal), SignatureModel(DriveTrain.from_dict(raw, source="soft belt"))


def test_creep_mismatch_is_the_rms_belt_level_over_the_nominal_creep(models):
    nominal, soft = models
    creep = nominal_creep(nominal)
    assert 1e-4 < creep < 5e-3  # a V-belt's elastic creep: a fraction of a per cent
    # a 30 % softer belt creeps 1/0.7 as much: the rollers lag by the extra creep
    assert nominal_creep(soft) == pytest.approx(creep / 0.7, rel=0.02)
    assert creep_mismatch(nominal, np.array([0.3, -0.3, np.nan]) * creep) == pytest.approx(0.3)
    assert creep_mismatch(nominal, np.array([np.nan])) == 0.0


def test_mismatch_term_accepts_a_load_fault_on_a_soft_belt_machine(models):
    nominal, soft = models
    shift = soft.signature("front", "load_loss", 0.5)  # what the machine really does
    plain = rank_causes(nominal, shift, COV)
    allowed = rank_causes(nominal, shift, COV, creep_rel_sd=0.3)
    limit = chi2.isf(0.001, df=4)  # the lags: exact zeros here, no chi-square
    truth = {c.name: c for c in plain}["front:load_loss"]
    assert truth.chi2 > limit  # the nominal split is rejected: the creep part is 30 % off
    best = allowed[0]
    assert best.name == "front:load_loss" and best.chi2 < limit
    assert best.interval[0] <= 0.5 <= best.interval[1] or abs(best.severity - 0.5) < 0.05


def test_mismatch_term_does_not_turn_a_sensor_gain_into_a_machine_fault(models):
    nominal, _ = models
    shift = nominal.signature("motor", "gain", 0.003)
    assert rank_causes(nominal, shift, COV, creep_rel_sd=0.5)[0].name == "motor:gain"
