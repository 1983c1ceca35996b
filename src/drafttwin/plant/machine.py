"""The machine a recording is made of: its true parameters, apart from any one recording.

A machine is the nominal drive train with seeded deviations (friction, belt rigidity, mesh
and shaft stiffness, bearing drag, motor breakdown torque), backlash and gear eccentricity
phases. Recordings (noise, drafting force, supply jitter, data-path defects) are drawn
separately, so one machine can be recorded any number of times: calibrate on one record,
test on another.

By default the machine is drawn from the recording's own seed (what the plant always did, so
older files regenerate bit for bit); ``--machine-seed K`` draws it from ``K`` instead, and a
sidecar written by an earlier run (``--machine run.json``) gives back the very same machine.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drafttwin.errors import ConfigError, DataError
from drafttwin.mechanics import DriveTrain
from drafttwin.plant.config import PlantConfig
from drafttwin.plant.effects import true_train

_KINDS = ("roller", "belt", "chain", "gear", "shaft", "bearing")


@dataclass(frozen=True)
class Machine:
    """One machine: its true drive train and the relative deviations drawn for it.

    Attributes:
        train: the true drive train (what the plant simulates).
        draws: dotted parameter name -> relative deviation from nominal, e.g.
            ``{"roller.front.friction_coefficient": 0.05}``.
        seed: the machine seed it was drawn from (None if read from a file of unknown origin).
        source: where it came from (``"seed K"`` or the file it was read from).
    """

    train: DriveTrain
    draws: dict[str, float]
    seed: int | None
    source: str

    @classmethod
    def draw(cls, nominal: DriveTrain, config: PlantConfig, seed: int) -> Machine:
        """The machine drawn from ``seed`` around ``nominal`` (the plant's first stream)."""
        stream = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
        train, draws = true_train(nominal, config, stream)
        return cls(train, draws, seed, f"seed {seed}")

    @classmethod
    def load(cls, path: str | Path, nominal: DriveTrain) -> Machine:
        """The machine recorded in ``path``: a plant sidecar (``<stem>.json``) of an earlier
        run. It must be a machine of ``nominal``'s drive train (same elements)."""
        path = Path(path)
        where = "--machine"
        try:
            raw = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise DataError("no such file", source=path, where=where,
                            fix="give the .json sidecar that generate wrote beside its data") from None  # fmt: skip
        except (OSError, ValueError) as exc:
            raise DataError(f"not a readable JSON file ({exc})", source=path, where=where,
                            fix="give the .json sidecar that generate wrote") from None  # fmt: skip
        if not isinstance(raw, dict) or not {"true_train", "mismatch_draws"} <= set(raw):
            raise DataError("it names no machine (no true_train and mismatch_draws)",
                            source=path, where=where,
                            fix="give the .json sidecar that generate wrote") from None  # fmt: skip
        draws = raw["mismatch_draws"]
        if not isinstance(draws, dict) or not all(
            isinstance(v, int | float) and np.isfinite(v) for v in draws.values()
        ):
            raise DataError("mismatch_draws must map names to finite numbers", source=path,
                            where="mismatch_draws", fix="regenerate the file") from None  # fmt: skip
        train = DriveTrain.from_dict(raw["true_train"], source=str(path))
        _check_same_machine_kind(train, nominal, path)
        seed = raw.get("machine", {}).get("seed") if isinstance(raw.get("machine"), dict) else None
        return cls(train, {str(k): float(v) for k, v in draws.items()},
                   seed if isinstance(seed, int) else None, str(path))  # fmt: skip

    def describe(self) -> dict[str, Any]:
        """What the sidecar records about the machine (its parameters are beside it)."""
        return {"seed": self.seed, "source": self.source}


def _names(train: DriveTrain) -> dict[str, list[str]]:
    raw = train.to_dict()
    out = {kind: sorted(str(item.get("name", item.get("node"))) for item in raw.get(kind, []))
           for kind in _KINDS}  # fmt: skip
    out["node"] = sorted(train.node_names)
    return out


def _check_same_machine_kind(train: DriveTrain, nominal: DriveTrain, path: Path) -> None:
    mine, theirs = _names(train), _names(nominal)
    for kind, names in theirs.items():
        if mine[kind] != names:
            raise ConfigError(
                f"the machine in this file is not a {nominal.spec.train.name}: its {kind}s are "
                f"{', '.join(mine[kind]) or 'none'}, the drive train's {', '.join(names) or 'none'}",
                source=path,
                where="--machine",
                fix="give a sidecar generated with the same --preset/--config",
            )
