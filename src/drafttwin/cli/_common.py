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


CSV_FLOAT_FORMAT = "%.9g"
"""How the CSV files a command writes give their values (9 significant digits); a time
column is written whole (:func:`csv_ready`)."""


def csv_ready(frame: pd.DataFrame) -> pd.DataFrame:
    """``frame`` with its time column (named so, or a first column that only rises) as the
    shortest text that reads back exactly: at 9 significant digits an epoch time (1.8e9 s)
    loses everything below 10 s."""
    from pandas.api.types import is_float_dtype

    from drafttwin.data.validate import TIME_NAMES

    first = frame.columns[0] if len(frame.columns) else None  # a time named as the file named it
    names = [c for c in frame.columns if is_float_dtype(frame[c]) and (
        str(c).lower() in TIME_NAMES
        or (c == first and frame[c].dropna().is_monotonic_increasing))]  # fmt: skip
    if not names:
        return frame
    out = frame.copy()
    for c in names:
        out[c] = [repr(float(x)) if x == x else "" for x in frame[c].to_numpy()]
    return out


def write_frame(frame: pd.DataFrame, path: Path) -> None:
    """Write a DataFrame to CSV or Parquet atomically (nothing half-written on failure)."""
    from drafttwin._io import atomic_path

    check_output_suffix(path)
    with atomic_path(path) as tmp:
        if path.suffix.lower() == ".parquet":
            frame.to_parquet(tmp, index=False)
        else:
            csv_ready(frame).to_csv(tmp, index=False, float_format=CSV_FLOAT_FORMAT)
