"""The benchmark's plant records: what each scenario trains on and tests on.

Every record is made by the plant emulator (:class:`drafttwin.plant.Plant`) from the FA320A
preset. One machine (machine seed :data:`MACHINE_SEED`) is recorded at steady running at the
preset's VFD set-point for training; each scenario's test record is a separate recording
(its own record seed) of:

* ``speed+10`` ... ``speed-25``: the same machine at steady running with the set-point
  scaled by 1.10, 0.90, 1.25, 0.75;
* ``speed-change``, ``start-up``, ``stop``: the same machine, the plant's scenarios of those
  names (set-point lowered 15 % at half time; start from rest; ramp to standstill);
* ``draft-gears``: the same machine with other draft change gears (:data:`DRAFT_GEARS`:
  another total and break draft); the physics is given the new gear set, the learned models
  only the data;
* ``other-machine``: another machine of the type (machine seed :data:`OTHER_MACHINE_SEED`);
* ``little-data``: the training machine again at the preset's set-point (training records of
  10 ... 300 s are prefixes of the one training record).

Four separate validation records, never scored, choose the hybrids' structure
(:mod:`drafttwin.studies.generalisation.run`): steady running at the training set-point
(what a choice costs where the hybrid was trained), at +15 % and at -15 % speed (both
directions: a model can fail on one side of its training point only), and the plant's speed
change run from +15 % (a transient at set-points the scored records do not use).
"""

from __future__ import annotations

from dataclasses import dataclass

from drafttwin.data.series import MeasurementSeries
from drafttwin.mechanics import DriveTrain
from drafttwin.plant import Machine, Plant, PlantConfig

SCENARIOS = (
    "speed+10", "speed-10", "speed+25", "speed-25", "speed-change", "start-up", "stop",
    "draft-gears", "other-machine", "little-data",
)  # fmt: skip
"""The scored scenarios, in report order."""
MACHINE_SEED = 0
OTHER_MACHINE_SEED = 1
TRAIN_RECORD_SEED = 100
VALIDATION_RECORD_SEED = 199
DRAFT_GEARS = {"G-H": (20, 52), "I-J": (36, 28)}
"""Gear pair -> (driver, driven) teeth of the changed draft gears: the back roller geared
down (total draft 6.57 -> 6.98) and the break draft gear changed (1.20 -> 1.29); the mesh
frequencies stay far from the torsion modes (470-530 Hz)."""


@dataclass(frozen=True)
class RecordSpec:
    """One plant record: scenario, set-point scale, gear set, machine and record seed."""

    name: str
    plant_scenario: str = "steady"
    speed_scale: float = 1.0
    draft_gears: bool = False
    machine_seed: int = MACHINE_SEED
    record_seed: int = 0

    def describe(self) -> str:
        parts = [f"plant scenario {self.plant_scenario}"]
        if self.speed_scale != 1.0:
            parts.append(f"set-point x {self.speed_scale:g}")
        if self.draft_gears:
            parts.append("changed draft gears " + ", ".join(
                f"{k} {a}/{b}" for k, (a, b) in DRAFT_GEARS.items()))  # fmt: skip
        parts.append(f"machine seed {self.machine_seed}, record seed {self.record_seed}")
        return "; ".join(parts)


TEST_RECORDS: dict[str, RecordSpec] = {
    s.name: s
    for s in (
        RecordSpec("speed+10", speed_scale=1.10, record_seed=110),
        RecordSpec("speed-10", speed_scale=0.90, record_seed=90),
        RecordSpec("speed+25", speed_scale=1.25, record_seed=125),
        RecordSpec("speed-25", speed_scale=0.75, record_seed=75),
        RecordSpec("speed-change", plant_scenario="speed-change", record_seed=101),
        RecordSpec("start-up", plant_scenario="startup", record_seed=102),
        RecordSpec("stop", plant_scenario="stop", record_seed=103),
        RecordSpec("draft-gears", draft_gears=True, record_seed=104),
        RecordSpec("other-machine", machine_seed=OTHER_MACHINE_SEED, record_seed=105),
        RecordSpec("little-data", record_seed=106),
    )
}
TRAIN_RECORD = RecordSpec("train", record_seed=TRAIN_RECORD_SEED)
VALIDATION_RECORDS: dict[str, RecordSpec] = {
    "validation-nominal": RecordSpec("validation: steady at the training set-point",
                                     record_seed=VALIDATION_RECORD_SEED + 3),
    "validation": RecordSpec("validation: steady at +15 %", speed_scale=1.15,
                             record_seed=VALIDATION_RECORD_SEED),
    "validation-low": RecordSpec("validation: steady at -15 %", speed_scale=0.85,
                                 record_seed=VALIDATION_RECORD_SEED + 2),
    "validation-transient": RecordSpec("validation: speed change from +15 %",
                                       plant_scenario="speed-change", speed_scale=1.15,
                                       record_seed=VALIDATION_RECORD_SEED + 1),
}  # fmt: skip


def nominal_train(draft_gears: bool = False) -> DriveTrain:
    """The FA320A preset, with the changed draft gears if asked (what the physics knows)."""
    train = DriveTrain.preset("fa320a")
    if not draft_gears:
        return train
    raw = train.to_dict()
    for gear in raw["gear"]:
        if gear["name"] in DRAFT_GEARS:
            gear["driver_teeth"], gear["driven_teeth"] = DRAFT_GEARS[gear["name"]]
    raw["train"]["name"] = f"{raw['train']['name']} (changed draft gears)"
    return DriveTrain.from_dict(raw, source="fa320a preset with changed draft gears")


def _with_supply(train: DriveTrain, scale: float) -> DriveTrain:
    """``train`` with its VFD set-point scaled (the plant ramps its scenarios to it)."""
    if scale == 1.0:
        return train
    raw = train.to_dict()
    raw["motor"]["supply_hz"] = raw["motor"]["supply_hz"] * scale
    return DriveTrain.from_dict(raw, source=f"{train.source} at set-point x {scale:g}")


def make_record(spec: RecordSpec, duration_s: float, rate_hz: float) -> MeasurementSeries:
    """The measured series of ``spec`` (with the true speeds and the set-point input)."""
    gears = nominal_train(spec.draft_gears)
    config = PlantConfig()
    # the machine is drawn around the gear set it runs with: same seed, same deviations
    machine = Machine.draw(gears, config, spec.machine_seed)
    plant = Plant(_with_supply(gears, spec.speed_scale), config)
    rec = plant.run(duration_s, rate_hz, seed=spec.record_seed, scenario=spec.plant_scenario,
                    machine=machine)  # fmt: skip
    return rec.series
