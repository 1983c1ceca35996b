"""The embedded default data set: the FA320A plant, steady running, seeded.

``load_default()`` reads it from the package (no download); ``build()`` regenerates it
bit-identically (``python -m drafttwin.datasets``).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any, TypedDict

import pandas as pd

from drafttwin._constants import ROLLERS
from drafttwin.data.series import MeasurementSeries


class PlantRun(TypedDict):
    """How the plant emulator is run to make a data set."""

    seed: int
    duration_s: float
    rate_hz: float
    scenario: str


DEFAULT: PlantRun = {"seed": 20260101, "duration_s": 300.0, "rate_hz": 100.0, "scenario": "steady"}
_FILE = "fa320a_default.parquet"


def default_path() -> Path:
    return Path(str(resources.files("drafttwin.datasets") / _FILE))


def _series(frame: pd.DataFrame, info: dict[str, Any]) -> MeasurementSeries:
    truth = frame[[f"true_{r}" for r in ROLLERS]].to_numpy()
    meta = {
        "source": "drafttwin default data set (plant emulator)",
        **{k: info[k] for k in ("seed", "scenario", "duration_s", "rate_hz")},
        "true_motor_rpm": frame["true_motor"].to_numpy(),
        "missing_mask": frame[[f"missing_{r}" for r in ROLLERS]].to_numpy(bool),
        "outlier_mask": frame[[f"outlier_{r}" for r in ROLLERS]].to_numpy(bool),
        "plant": info,
    }
    return MeasurementSeries(
        time_s=frame["time"].to_numpy(),
        values=frame[list(ROLLERS)].to_numpy(),
        inputs={"supply_hz": frame["supply_hz"].to_numpy()},
        truth=truth,
        metadata=meta,
    )


def load_default() -> MeasurementSeries:
    """The default data set: 5 min of FA320A roller speeds at 100 Hz from the plant emulator.

    ``truth`` holds the true roller speeds; ``metadata`` carries ``true_motor_rpm``,
    ``missing_mask`` and ``outlier_mask`` (where the plant dropped / spiked samples), and
    ``plant`` (seed, true parameters, effects).
    """
    import pyarrow.parquet as pq

    table = pq.read_table(default_path())
    info = json.loads(table.schema.metadata[b"drafttwin.plant"])
    return _series(table.to_pandas(), info)


def build(
    duration_s: float | None = None, progress: Callable[[float], None] | None = None
) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Regenerate the default data set (or its first ``duration_s`` seconds)."""
    from drafttwin.plant import Plant, PlantConfig
    from drafttwin.plant.config import Eccentricity

    spec = DEFAULT.copy()
    if duration_s is not None:
        spec["duration_s"] = duration_s
    # made when the plant gave every gear its allowable run-out and placed the machine at its
    # operating point, and kept so whatever the plant's defaults: the study's figures are
    # those of this very record
    config = PlantConfig(eccentricity=Eccentricity(gear_runout_law="allowable"),
                         start="operating-point")  # fmt: skip
    rec = Plant(config=config).run(spec["duration_s"], spec["rate_hz"], seed=spec["seed"],
                      scenario=spec["scenario"], progress=progress)  # fmt: skip
    frame = rec.series.to_frame()
    truth = rec.truth_frame().drop(columns="time")
    return pd.concat([frame, truth], axis=1), rec.info


def write_default(path: Path | None = None) -> Path:
    import pyarrow as pa
    import pyarrow.parquet as pq

    from drafttwin._io import atomic_path

    frame, info = build()
    table = pa.Table.from_pandas(frame, preserve_index=False)
    table = table.replace_schema_metadata(
        {b"drafttwin.plant": json.dumps(info, sort_keys=True).encode()}
    )
    target = path or default_path()
    with atomic_path(target) as tmp:
        pq.write_table(table, tmp, compression="zstd")
    return target


__all__ = ["DEFAULT", "build", "default_path", "load_default", "write_default"]
