"""Shared test setup: one torch thread (the test machine is shared), synthetic series, and
the helpers every model test uses (``tests/_synthetic.py``)."""

from __future__ import annotations

import pytest

from drafttwin.data.series import MeasurementSeries
from drafttwin.models import MechanisticModel

from ._synthetic import make_series, mechanistic, one_thread


@pytest.fixture(autouse=True, scope="session")
def _one_torch_thread():
    with one_thread():
        yield


@pytest.fixture(scope="module")
def series() -> MeasurementSeries:
    """200 rows of synthetic roller speeds (seed 3)."""
    return make_series(200, seed=3)[0]


@pytest.fixture(scope="module")
def mech() -> MechanisticModel:
    """The synthetic mechanistic source (a function of time)."""
    return MechanisticModel(mechanistic)
