"""Writing a (calibrated) drive train as a TOML declaration that ``--config`` reads back."""

from __future__ import annotations

from pathlib import Path

import tomli_w

from drafttwin._io import write_text_atomic
from drafttwin.mechanics import DriveTrain


def train_toml(train: DriveTrain, header: str = "") -> str:
    """The declaration as TOML text (a comment header first, when given)."""
    text = tomli_w.dumps(train.to_dict())
    lines = [f"# {line}" for line in header.splitlines()] if header else []
    return "\n".join([*lines, text]) if lines else text


def write_train(train: DriveTrain, path: str | Path, header: str = "") -> Path:
    """Write ``train`` to ``path`` atomically; it reads back as the same train."""
    target = Path(path)
    write_text_atomic(target, train_toml(train, header))
    return target
