"""Option helpers shared by command modules."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from drafttwin.errors import ConfigError

if TYPE_CHECKING:
    import pandas as pd

    from drafttwin.mechanics import DriveTrain


def load_train(preset: str | None, config: Path | None) -> DriveTrain:
    """The drive train named by ``--preset`` or ``--config`` (exactly one may be given)."""
    from drafttwin.models.mechanistic.source import PhysicsSource
    from drafttwin.models.registry import drive_train

    if preset and config:
        raise ConfigError(
            "both --preset and --config were given",
            where="options",
            fix="give one of them",
        )
    if config is not None:
        return drive_train(PhysicsSource("config", paths=(Path(config),)), where="--config")
    return drive_train(PhysicsSource("preset", preset=preset or "fa320a"), where="--preset")


def check_output_suffix(path: Path, option: str = "--out") -> None:
    """Refuse an output file whose suffix is neither .csv nor .parquet."""
    if path.suffix.lower() not in (".csv", ".parquet"):
        raise ConfigError(
            f"unsupported output file type '{path.suffix or '(none)'}'",
            source=path,
            where=option,
            fix="name the output file *.csv or *.parquet",
        )


def write_frame(frame: pd.DataFrame, path: Path) -> None:
    """Write a DataFrame to CSV or Parquet atomically (nothing half-written on failure)."""
    from drafttwin._io import atomic_path

    check_output_suffix(path)
    with atomic_path(path) as tmp:
        if path.suffix.lower() == ".parquet":
            frame.to_parquet(tmp, index=False)
        else:
            frame.to_csv(tmp, index=False, float_format="%.9g")
