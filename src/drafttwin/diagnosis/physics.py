"""The physics a diagnosis runs on: the drive train of a fitted model file, or a train named
directly (``preset``, ``preset:NAME``, ``config:FILE.toml``)."""

from __future__ import annotations

from drafttwin.mechanics import DriveTrain


def physics_train(model: str) -> DriveTrain:
    """The drive train named by ``--model``."""
    from drafttwin.models.registry import drive_train

    return drive_train(model, where="--model")
