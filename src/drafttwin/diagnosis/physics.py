"""The physics a diagnosis runs on: the drive train of a fitted model file, or a train named
directly (``preset``, ``preset:NAME``, ``config:FILE.toml``)."""

from __future__ import annotations

from pathlib import Path

from drafttwin.errors import ConfigError
from drafttwin.mechanics import DriveTrain


def physics_train(model: str) -> DriveTrain:
    """The drive train named by ``--model``."""
    kind, _, rest = model.partition(":")
    if model == "preset" or kind == "preset":
        return DriveTrain.preset(rest or "fa320a")
    if kind == "config":
        return DriveTrain.from_toml(Path(rest))
    from drafttwin.models.registry import load_model

    fitted = load_model(Path(model))
    spec = getattr(fitted, "mechanistic_spec_", None) or {}
    if spec.get("kind") == "preset":
        return DriveTrain.preset(str(spec["name"]))
    if spec.get("kind") == "train":
        return DriveTrain.from_dict(dict(spec["spec"]), source=f"model file {model}")
    raise ConfigError(
        f"the model in this file ({type(fitted).__name__}) carries no drive train "
        f"(its physics: {spec.get('kind', 'none')})",
        source=model,
        where="--model",
        fix="fit a model on a drive-train physics (fit --mechanistic preset or config:FILE.toml), "
        "or give --model preset / config:FILE.toml",
    )
