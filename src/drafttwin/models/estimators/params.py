"""Estimator hyperparameters: the checks of the flat ones, and their JSON form in model files.

Hyperparameters are plain values (numbers, strings, booleans, tuples) or settings objects:
a :class:`~drafttwin.models.estimators.task.Task`, a :class:`~drafttwin.models.training.Training`, or an
unfitted estimator used as a template (MD-S-L's data-driven model). Model files store them as
JSON, each object tagged with its kind, and never as pickles.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

from drafttwin.errors import ConfigError
from drafttwin.models.estimators.task import Task
from drafttwin.models.training import Training

MAX_WINDOW = 1_000_000
"""Longest input window, samples (a model file asking for more is damaged, not ambitious)."""
MAX_WIDTH = 4096
"""Widest recurrent layer or SKNet: bounds the memory a model file can make ``load`` take."""
MAX_LAYERS = 16
"""Most stacked recurrent layers."""
MAX_SEED = 2**63 - 1


def _int_at_least(low: int, high: int = MAX_SEED) -> Callable[[Any], bool]:
    return lambda v: isinstance(v, int) and not isinstance(v, bool) and low <= v <= high


def _fraction(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and 0 <= v < 1


def _optional_bool(v: Any) -> bool:
    return v is None or isinstance(v, bool)


CHECKS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "window": (_int_at_least(1, MAX_WINDOW), f"an integer in [1, {MAX_WINDOW}] (samples)"),
    "hidden": (_int_at_least(1, MAX_WIDTH), f"an integer in [1, {MAX_WIDTH}]"),
    "layers": (_int_at_least(1, MAX_LAYERS), f"an integer in [1, {MAX_LAYERS}]"),
    "folds": (_int_at_least(2, 1000), "an integer in [2, 1000]"),
    "val_folds": (_int_at_least(1, 20), "an integer in [1, 20] (1: the validation tail only)"),
    "seed": (_int_at_least(0), f"an integer in [0, {MAX_SEED}]"),
    "sk_channels": (
        lambda v: _int_at_least(3, MAX_WIDTH)(v) and v % 3 == 0,
        f"a multiple of 3 in [3, {MAX_WIDTH}]",
    ),  # fmt: skip
    "dropout": (_fraction, "in [0, 1)"),
    "skip": (_optional_bool, "None (the default for the task), True or False"),
    "accumulate": (_optional_bool, "None (chosen on validation data), True or False"),
    "structure": (lambda v: v in ("absolute", "relative"), '"absolute" or "relative"'),
    "fade": (lambda v: isinstance(v, bool) or v == "strict", 'True, False or "strict"'),
    "fallback": (lambda v: isinstance(v, bool), "True or False"),
    "quiet": (lambda v: isinstance(v, bool), "True or False"),
    "use_disagreement": (lambda v: isinstance(v, bool), "True or False"),
    "task": (lambda v: isinstance(v, Task), "a drafttwin.models.Task"),
    "training": (lambda v: isinstance(v, Training), "a drafttwin.models.Training"),
}
"""Per-hyperparameter rule and its wording for the error message."""


ADDED_LATER: dict[str, Any] = {"structure": "absolute", "fade": False, "fallback": False,
                               "val_folds": 1}  # fmt: skip
"""Hyperparameters added after model files were first written, with the value that keeps the
older behaviour: a file without them is read with these."""


def first_invalid(params: Mapping[str, Any]) -> tuple[str, str] | None:
    """``(name, rule)`` of the first plain hyperparameter (not a settings object, as stored in
    a model file) that breaks its rule, else ``None``."""
    for key, value in params.items():
        rule = CHECKS.get(key)
        if rule is not None and not isinstance(value, dict) and not rule[0](value):
            return key, rule[1]
    return None


def check_params(owner: str, params: Mapping[str, Any]) -> None:
    """Raise :class:`ConfigError` for the first hyperparameter that breaks its rule."""
    for key, value in params.items():
        rule = CHECKS.get(key)
        if rule is not None and not rule[0](value):
            raise ConfigError(f"hyperparameter {{{key}}} is invalid for {owner}",
                              terms={key: value}, fix=f"{{{key}:name}} must be {rule[1]}")  # fmt: skip


def encode(value: Any) -> Any:
    """A hyperparameter value as JSON-able data (settings objects tagged by kind)."""
    if isinstance(value, Task):
        return {"__task__": value.to_dict()}
    if isinstance(value, Training):
        return {"__training__": value.to_dict()}
    if hasattr(value, "get_params") and hasattr(value, "param_names"):
        params = encode_params(value.get_params(deep=False))
        return {"__model__": type(value).__name__, "params": params}
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
