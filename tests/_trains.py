"""Small drive trains for mechanics tests."""

from __future__ import annotations

import copy
from typing import Any

from drafttwin.mechanics import DriveTrain

FA320A = DriveTrain.preset("fa320a")


def fa320a_dict() -> dict[str, Any]:
    return copy.deepcopy(FA320A.to_dict())


def two_inertia_gear(j1: float = 0.01, j2: float = 0.002, k: float = 2.0e8) -> dict[str, Any]:
    """Motor inertia meshing with one load inertia: no backlash, constant stiffness."""
    return {
        "motor": {"node": "a", "rated_power_w": 1000, "rated_rpm": 1440, "poles": 4,
                  "supply_hz": 50.0, "torque_lag_s": 0.005},
        "inertia": [{"name": "a", "inertia_kgm2": j1}, {"name": "b", "inertia_kgm2": j2}],
        "gear": [{"name": "ab", "driver": "a", "driven": "b", "driver_teeth": 30,
                  "driven_teeth": 20, "module_mm": 2.0, "mesh_stiffness_n_per_m": k,
                  "harmonics": 0, "backlash_um": 0.0, "damping_ratio": 0.0}],
        "bearing": [{"node": "b", "coulomb_torque_nm": 0.0, "viscous_nms": 1e-4}],
        "solver": {"dt_s": 1e-6, "output_rate_hz": 20000.0, "settle_s": 0.0},
    }  # fmt: skip
