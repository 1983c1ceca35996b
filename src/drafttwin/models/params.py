"""Estimator hyperparameters: the checks of the flat ones, and their JSON form in model files.

Hyperparameters are plain values (numbers, strings, booleans, tuples) or settings objects:
a :class:`~drafttwin.models.task.Task`, a :class:`~drafttwin.models.training.Training`, or an
unfitted estimator used as a template (MD-S-L's data-driven model). Model files store them as
JSON, each object tagged with its kind, and never as pickles.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

from drafttwin.errors import ConfigError
from drafttwin.models.task import Task
from drafttwin.models.training import Training


def _int_at_least(low: int) -> Callable[[Any], bool]:
    return lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= low


def _optional_bool(v: Any) -> bool:
    return v is None or isinstance(v, bool)


CHECKS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "window": (_int_at_least(1), "an integer >= 1 (samples)"),
    "hidden": (_int_at_least(1), "an integer >= 1"),
    "layers": (_int_at_least(1), "an integer >= 1"),
    "folds": (_int_at_least(2), "an integer >= 2"),
    "seed": (_int_at_least(0), "an integer >= 0"),
    "sk_channels": (lambda v: _int_at_least(3)(v) and v % 3 == 0, "a multiple of 3"),
    "dropout": (lambda v: isinstance(v, int | float) and 0 <= v < 1, "in [0, 1)"),
    "skip": (_optional_bool, "None (the default for the task), True or False"),
    "accumulate": (_optional_bool, "None (chosen on validation data), True or False"),
    "quiet": (lambda v: isinstance(v, bool), "True or False"),
    "use_disagreement": (lambda v: isinstance(v, bool), "True or False"),
    "task": (lambda v: isinstance(v, Task), "a drafttwin.models.Task"),
    "training": (lambda v: isinstance(v, Training), "a drafttwin.models.Training"),
}
"""Per-hyperparameter rule and its wording for the error message."""


def check_params(owner: str, params: Mapping[str, Any]) -> None:
    """Raise :class:`ConfigError` for the first hyperparameter that breaks its rule."""
    for key, value in params.items():
        rule = CHECKS.get(key)
        if rule is not None and not rule[0](value):
            raise ConfigError(f"hyperparameter {key}={value!r} is invalid for {owner}",
                              fix=f"{key} must be {rule[1]}")  # fmt: skip


def encode(value: Any) -> Any:
    """A hyperparameter value as JSON-able data (settings objects tagged by kind)."""
    if isinstance(value, Task):
        return {"__task__": value.to_dict()}
    if isinstance(value, Training):
        return {"__training__": value.to_dict()}
    if hasattr(value, "get_params") and hasattr(value, "param_names"):
        return {"__model__": type(value).__name__, "params": encode_params(value.get_params())}
    if isinstance(value, tuple):
        return list(value)
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"hyperparameter value {value!r} is not finite")
    return value


def encode_params(params: Mapping[str, Any]) -> dict[str, Any]:
    return {k: encode(v) for k, v in params.items()}


def decode(value: Any, classes: Mapping[str, type]) -> Any:
    """The inverse of :func:`encode`; ``classes`` maps estimator class names to classes."""
    if isinstance(value, dict) and "__task__" in value:
        return Task.from_dict(value["__task__"])
    if isinstance(value, dict) and "__training__" in value:
        return Training(**value["__training__"])
    if isinstance(value, dict) and "__model__" in value:
        cls = classes.get(str(value["__model__"]))
        if cls is None:
            raise ValueError(f"unknown estimator class {value['__model__']!r}")
        return cls(**decode_params(value["params"], classes))
    return value


def decode_params(params: Mapping[str, Any], classes: Mapping[str, type]) -> dict[str, Any]:
    return {k: decode(v, classes) for k, v in params.items()}
