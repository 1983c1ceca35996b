"""Seeded fault scenarios: healthy and faulty plant records with their labels.

:func:`draw_cases` draws, from one seed, which machine each case records, which fault (if
any) it carries, how severe (the kind's light / moderate / severe level), abrupt or incipient
(a ramp over 30 % of the record) and when it starts (30-50 % into the record). One case in
``healthy_every`` is healthy. :func:`run_case` runs the plant for one case.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from drafttwin.mechanics import DriveTrain
from drafttwin.plant.emulator import Plant, PlantRecording
from drafttwin.plant.faults import KINDS, FaultSpec, catalogue
from drafttwin.plant.machine import Machine

LEVELS = ("light", "moderate", "severe")


@dataclass(frozen=True)
class FaultCase:
    """One record to generate: machine and recording seeds and the faults injected."""

    name: str
    machine_seed: int
    seed: int
    faults: tuple[FaultSpec, ...]
    level: str | None  # light | moderate | severe, None when healthy

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "machine_seed": self.machine_seed, "seed": self.seed,
                "level": self.level, "faults": [f.label() for f in self.faults]}  # fmt: skip


def fault_pairs(train: DriveTrain) -> list[tuple[str, str]]:
    """Every (element, kind) of ``train`` in a fixed order."""
    return sorted((e, k) for e, kinds in catalogue(train).items() for k in kinds)


def make_fault(element: str, kind: str, level: int, abrupt: bool, onset_s: float,
               duration_s: float, sign: float = 1.0) -> FaultSpec:  # fmt: skip
    """The fault ``element:kind`` at a level (0 light .. 2 severe) starting at ``onset_s``."""
    k = KINDS[kind]
    severity = k.levels[level] * (sign if k.signed else 1.0)
    if kind == "stuck":  # a stuck value cannot outlast the record
        severity = min(severity, max(duration_s - onset_s, 1e-3))
    ramp = 0.0 if abrupt or not k.ramp_allowed else 0.3 * duration_s
    return FaultSpec(element=element, kind=kind, severity=severity, onset_s=onset_s, ramp_s=ramp)


def draw_cases(train: DriveTrain, n_cases: int, seed: int, duration_s: float,
               healthy_every: int = 4) -> list[FaultCase]:  # fmt: skip
    """``n_cases`` seeded cases; cases ``0, healthy_every, ...`` are healthy."""
    rng = np.random.default_rng(seed)
    pairs = fault_pairs(train)
    cases = []
    for i in range(n_cases):
        machine_seed, rec_seed = (int(x) for x in rng.integers(0, 2**31, size=2))
        element, kind = pairs[int(rng.integers(len(pairs)))]
        level = int(rng.integers(3))
        abrupt = bool(rng.random() < 0.5)
        onset = float(np.round(rng.uniform(0.3, 0.5) * duration_s, 2))
        sign = 1.0 if rng.random() < 0.5 else -1.0
        if i % healthy_every == 0:
            cases.append(FaultCase(f"case_{i:04d}", machine_seed, rec_seed, (), None))
            continue
        fault = make_fault(element, kind, level, abrupt, onset, duration_s, sign)
        cases.append(FaultCase(f"case_{i:04d}", machine_seed, rec_seed, (fault,), LEVELS[level]))
    return cases


def run_case(plant: Plant, case: FaultCase, duration_s: float, rate_hz: float,
             scenario: str = "steady", progress: Any = None) -> PlantRecording:  # fmt: skip
    """The plant record of one case (its machine drawn from ``case.machine_seed``)."""
    machine = Machine.draw(plant.train, plant.config, case.machine_seed)
    return plant.run(duration_s, rate_hz, seed=case.seed, scenario=scenario, machine=machine,
                     faults=case.faults, progress=progress)  # fmt: skip
