"""The plant's reduced option (``Plant(reduced_hz=...)``): explicit, recorded, healthy only."""

import numpy as np
import pytest

from drafttwin.errors import ConfigError
from drafttwin.plant import Machine, Plant
from drafttwin.plant.fault_cases import make_fault


def test_default_plant_is_the_full_train_and_records_no_reduction():
    plant = Plant()
    assert plant.reduced_hz is None
    rec = plant.run(3.0, seed=4)
    assert "reduced" not in rec.info


def test_reduced_plant_records_its_reduction_and_keeps_machine_and_speeds():
    full, red = Plant(), Plant(reduced_hz=200.0)
    machine = Machine.draw(full.train, full.config, 11)
    a = full.run(5.0, seed=3, machine=machine)
    b = red.run(5.0, seed=3, machine=machine)
    assert b.info["reduced"]["cutoff_hz"] == 200.0
    assert "main_belt" not in b.info["reduced"]["rigid"]  # belts stay compliant
    assert b.info["true_train"] == a.info["true_train"]  # the same machine, not its reduction
    # the same machine and seed run at the same mean speeds (within 0.02 %)
    rel = np.nanmean(b.true_rpm, axis=0) / np.nanmean(a.true_rpm, axis=0) - 1.0
    assert np.abs(rel).max() < 2e-4
    assert red.run(5.0, seed=3, machine=machine).series.values.tobytes() == (
        b.series.values.tobytes()
    )  # seeded


def test_reduced_plant_refuses_machine_faults_surfaces_and_bad_cutoffs():
    red = Plant(reduced_hz=200.0)
    wear = make_fault("E-F", "wear", 2, True, 1.0, 3.0)
    with pytest.raises(ConfigError, match="machine faults wear"):
        red.run(3.0, seed=1, faults=[wear])
    with pytest.raises(ConfigError, match="roller surfaces"):
        red.run(3.0, seed=1, surface_rate_hz=1000.0)
    with pytest.raises(ConfigError, match="cut-off"):
        Plant(reduced_hz=-5.0)
    # a sensor fault acts on the readings only: allowed
    gain = make_fault("front", "gain", 2, True, 1.0, 3.0)
    assert red.run(3.0, seed=1, faults=[gain]).info["faults"][0]["kind"] == "gain"
