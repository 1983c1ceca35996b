"""The output-error refit of the EMPS physics and the benchmark's physics variants.

No data needed: the refit is checked in closed loop on a record simulated with known
parameters from a synthetic drive signal.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from drafttwin.errors import ConfigError
from drafttwin.execution.store import public
from drafttwin.studies.emps.physics import REFIT_FIELDS, EmpsPhysics, refit
from drafttwin.studies.emps.plan import EmpsConfig, task_configs, variant_name


def _drive(n: int) -> np.ndarray:
    """A drive voltage that moves the carriage both ways, with stops (stick and slip)."""
    t = np.arange(n) * 1e-3
    v = 2.5 * np.sin(2 * np.pi * 0.7 * t) + 1.2 * np.sin(2 * np.pi * 2.3 * t + 0.4)
    return np.where(np.abs(np.sin(2 * np.pi * 0.25 * t)) < 0.15, 0.0, v)


def test_refit_recovers_the_parameters_a_record_was_simulated_with() -> None:
    truth = replace(EmpsPhysics(), mass_kg=82.0, viscous_ns_per_m=175.0, coulomb_n=24.0,
                    offset_n=-2.2)  # fmt: skip
    vir = _drive(3000)
    qm = truth.simulate(vir, 0.1)
    qm = qm + np.random.default_rng(0).normal(0.0, 2e-6, len(qm))  # a 2 µm encoder noise
    fit = refit(vir, qm)  # starts from the published values, 14-30 % away
    assert fit.initial == EmpsPhysics()
    for name in REFIT_FIELDS:
        assert getattr(fit.physics, name) == pytest.approx(getattr(truth, name), rel=0.01), name
    assert fit.rmse_mm < 0.01 < fit.rmse_mm_initial
    assert fit.physics.gtau_n_per_v == truth.gtau_n_per_v  # not refitted
    again = refit(vir, qm)
    assert again.physics == fit.physics and again.nfev == fit.nfev  # deterministic
    assert set(fit.to_dict()["parameters"]) == set(REFIT_FIELDS)


def test_refit_keeps_physical_bounds() -> None:
    vir = _drive(1500)
    # a record with no friction at all: Fv and Fc must stop at 0, not go negative
    frictionless = replace(EmpsPhysics(), viscous_ns_per_m=0.0, coulomb_n=0.0)
    fit = refit(vir, frictionless.simulate(vir, 0.0))
    assert fit.physics.viscous_ns_per_m >= 0.0 and fit.physics.coulomb_n >= 0.0
    assert fit.physics.mass_kg > 0.0


def test_published_task_configs_are_unchanged_by_the_variants() -> None:
    plain = task_configs(EmpsConfig())
    refitted = replace(EmpsPhysics(), mass_kg=90.0)
    both = task_configs(EmpsConfig(physics_variants=("published", "refitted")), refitted)
    published = [c for c in both if c["_physics_name"] in (None, "published")]
    assert [public(c) for c in published] == [public(c) for c in plain]  # same task keys
    extra = [c for c in both if c["_physics_name"] == "refitted"]
    assert {c["model"] for c in extra} == {"mechanistic", "parallel", "md-s-l"}
    assert all(c["physics"]["mass_kg"] == 90.0 for c in extra)
    assert len(extra) == 2 * (1 + 3 + 3)  # tasks x (physics once, two hybrids x 3 seeds)
    assert variant_name("parallel", "refitted") == "parallel_refitted"
    assert variant_name("gru", None) == variant_name("gru", "published") == "gru"
    with pytest.raises(ConfigError, match="--physics"):
        EmpsConfig(physics_variants=("fitted",)).check()
