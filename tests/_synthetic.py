"""Synthetic roller-speed series for the model tests (no plant emulator needed).

Speeds around 1815/435/426/355 rpm: a few sinusoids (the "dynamics"), AR(1) colored
fluctuation and white sensor noise. The "mechanistic" prediction is a function of time only:
the clean signal with a 0.2 % offset and without its slowest component.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator

import numpy as np
import torch

from drafttwin.data.series import MeasurementSeries

BASE_RPM = np.array([1815.0, 435.0, 426.0, 355.0])
DT_S = 0.01

TINY = {
    "window": 8,
    "hidden": 8,
    "layers": 1,
    "epochs": 2,
    "batch_size": 64,
    "patience": 2,
    "quiet": True,
    "device": "cpu",
}
"""Hyperparameters small enough for unit tests (fits in a fraction of a second)."""

TINY_MDSL = {
    **TINY,
    "sk_channels": 6,
    "data_window": 8,
    "data_hidden": 8,
    "data_layers": 1,
    "folds": 2,
}


def _components(time_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(time_s, dtype=np.float64)[:, None]
    fast = 0.002 * np.sin(2 * np.pi * t / 0.37 + np.arange(4)) + 0.001 * np.sin(
        2 * np.pi * t / 0.11
    )
    slow = 0.003 * np.sin(2 * np.pi * t / 2.3 + 0.5 * np.arange(4))
    return BASE_RPM * fast, BASE_RPM * slow


def clean_signal(time_s: np.ndarray) -> np.ndarray:
    """True speeds (n, 4) rpm."""
    fast, slow = _components(time_s)
    return BASE_RPM + fast + slow


def mechanistic(time_s: np.ndarray) -> np.ndarray:
    """A mechanistic prediction (n, 4) rpm: offset by 0.2 %, slow component missing."""
    fast, _ = _components(time_s)
    return BASE_RPM * 1.002 + fast


def make_series(
    n: int = 360, seed: int = 0, missing: float = 0.0
) -> tuple[MeasurementSeries, np.ndarray]:
    """A measured series and the true speeds (n, 4) rpm."""
    rng = np.random.default_rng(seed)
    time_s = np.arange(n) * DT_S
    true = clean_signal(time_s)
    ar = np.zeros((n, 4))
    shocks = rng.normal(0.0, 0.0004, (n, 4)) * BASE_RPM
    for i in range(1, n):
        ar[i] = 0.9 * ar[i - 1] + shocks[i]
    true = true + ar
    measured = true + rng.normal(0.0, 0.0002, (n, 4)) * BASE_RPM
    if missing > 0:
        measured[rng.random((n, 4)) < missing] = np.nan
    return MeasurementSeries(time_s=time_s, values=measured), true


def mechanistic_source() -> Callable[[np.ndarray], np.ndarray]:
    return mechanistic


@contextlib.contextmanager
def one_thread() -> Iterator[None]:
    """Run torch on one CPU thread (the test machine is shared), restoring the setting."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def hyper_for(name: str, **extra: object) -> dict[str, object]:
    """Tiny hyperparameters for registry model ``name`` (hybrids keep their residual model
    even where it loses to the physics on validation: the tests here are about that model)."""
    if name == "mechanistic":
        base: dict[str, object] = {}
    elif name == "persistence":
        base = {}
    elif name.startswith("md"):
        base = dict(TINY_MDSL)
    else:
        base = dict(TINY)
    if name == "parallel" or name.startswith("md"):
        base["fallback"] = False
    return {**base, **extra}
