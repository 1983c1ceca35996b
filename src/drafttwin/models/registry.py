"""Model registry: build estimators by name under a profile, and load model files."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from drafttwin.errors import ConfigError
from drafttwin.mechanics import DriveTrain
from drafttwin.models.estimators.base import MODEL_CLASSES, BaseModel, read_model_file
from drafttwin.models.estimators.baselines import MechanisticBaseline, PersistenceModel
from drafttwin.models.estimators.datadriven import GRUModel, LSTMModel
from drafttwin.models.estimators.mdsl import MDSL
from drafttwin.models.estimators.parallel import ParallelHybrid
from drafttwin.models.estimators.task import Task
from drafttwin.models.mechanistic.source import PhysicsSource, parse_source
from drafttwin.models.profiles import DEFAULT_PROFILE, PROFILES, Profile
from drafttwin.models.training import Training

MODEL_NAMES: tuple[str, ...] = (
    "mechanistic",
    "persistence",
    "gru",
    "lstm",
    "parallel",
    "md-s-l",
    "md-l",
    "md-s",
    "md-s-l+d",
)
"""Names accepted by :func:`make_model` (``md-s-l+d``: MD-S-L with the disagreement input)."""

_FACTORIES: dict[str, tuple[type[BaseModel], dict[str, Any]]] = {
    "mechanistic": (MechanisticBaseline, {}),
    "persistence": (PersistenceModel, {}),
    "gru": (GRUModel, {}),
    "lstm": (LSTMModel, {}),
    "parallel": (ParallelHybrid, {}),
    "md-s-l": (MDSL, {"variant": "md-s-l"}),
    "md-l": (MDSL, {"variant": "md-l"}),
    "md-s": (MDSL, {"variant": "md-s"}),
    "md-s-l+d": (MDSL, {"variant": "md-s-l", "use_disagreement": True}),
}

TASK_FIELDS = tuple(f.name for f in dataclasses.fields(Task) if f.name != "kind")
TRAINING_FIELDS = tuple(f.name for f in dataclasses.fields(Training))
DATA_MODEL_FIELDS = {"data_window": "window", "data_hidden": "hidden", "data_layers": "layers"}
"""Shortcuts for MD models: ``data_hidden=64`` sets the data-driven model's ``hidden``."""


def model_class(name: str) -> type[BaseModel]:
    """The estimator class behind a registry name (``ConfigError`` for an unknown one)."""
    key = str(name).strip().lower()
    if key not in _FACTORIES:
        raise ConfigError(f"unknown model {name!r}", fix=f"use one of {', '.join(MODEL_NAMES)}")
    return _FACTORIES[key][0]


def get_profile(profile: str | Profile) -> Profile:
    """A :class:`Profile` by name (``quick``, ``standard``, ``paper``) or as given."""
    if isinstance(profile, Profile):
        return profile
    if profile not in PROFILES:
        raise ConfigError(f"unknown profile {profile!r}", fix=f"use one of {', '.join(PROFILES)}")
    return PROFILES[profile]


def make_model(name: str, profile: str | Profile = DEFAULT_PROFILE, **overrides: Any) -> BaseModel:
    """A new, unfitted estimator by registry name with the profile's hyperparameters,
    overridden by ``overrides``.

    Besides the constructor's own arguments, ``overrides`` may name the task's fields
    (``task="simulation"`` or a :class:`Task`, ``horizon``, ``outputs``, ``inputs``,
    ``init_samples``), the training settings (``epochs``, ``lr``, ``device``, ... ; for MD
    models they apply to the data-driven model too) and, for MD models, ``data_window``,
    ``data_hidden``, ``data_layers``. Raises :class:`ConfigError` for an unknown name, profile
    or option, naming the valid ones.
    """
    cls = model_class(name)
    key = str(name).strip().lower()
    fixed = _FACTORIES[key][1]
    accepted = set(cls.param_names())
    task = _task(overrides)
    params: dict[str, Any] = {**get_profile(profile).hyperparameters(key.removesuffix("+d"), task),
                              **fixed}  # fmt: skip
    params = {k: v for k, v in params.items() if k in accepted}
    params["task"] = task
    training = {k: overrides.pop(k) for k in TRAINING_FIELDS if k in overrides}
    data = {DATA_MODEL_FIELDS[k]: overrides.pop(k) for k in DATA_MODEL_FIELDS if k in overrides}
    unknown = sorted(set(overrides) - accepted)
    valid = sorted(accepted - {"task"})
    if training and "training" not in accepted:
        unknown += sorted(training)
    if data and "data_model" not in accepted:
        unknown += [f"data_{k}" for k in sorted(data)]
    if unknown:
        unknown = sorted(unknown)
        extra = [*TASK_FIELDS, "task"] + ([*TRAINING_FIELDS] if "training" in accepted else [])
        raise ConfigError(
            f"option(s) {unknown} do not apply to the {key} model",
            fix=f"valid: {', '.join(sorted(set(valid + extra)))}",
        )
    params.update(overrides)
    if training:
        params["training"] = params.get("training", Training()).replace(**training)
    if "data_model" in accepted:
        params["data_model"] = _data_model(params.get("data_model"), data, training)
    return cls(**params)


def _task(overrides: dict[str, Any]) -> Task:
    """The Task named by ``task=`` (a kind or a Task) and the task fields in ``overrides``
    (removed from it)."""
    given = overrides.pop("task", None)
    fields = {k: overrides.pop(k) for k in TASK_FIELDS if k in overrides}
    base = given if isinstance(given, Task) else Task(kind=given or "prediction")
    if isinstance(fields.get("outputs"), list):
        fields["outputs"] = tuple(fields["outputs"])
    if isinstance(fields.get("inputs"), list):
        fields["inputs"] = tuple(fields["inputs"])
    return base.replace(**fields) if fields else base


def _data_model(
    template: Any, data: dict[str, Any], training: dict[str, Any]
) -> GRUModel | LSTMModel:
    if template is not None and not isinstance(template, GRUModel | LSTMModel):
        raise ConfigError(
            f"data_model must be an unfitted GRUModel or LSTMModel, got {type(template).__name__}",
            fix="pass data_model=GRUModel(window=..., hidden=..., layers=...)",
        )
    if template is not None and not data and not training:
        return template
    base = template if template is not None else GRUModel()
    params = {**base.get_params(deep=False), **data}
    if training:
        params["training"] = params["training"].replace(**training)
    return type(base)(**params)


def load_model(path: str | Path) -> BaseModel:
    """Load any drafttwin model file (the class is read from the file)."""
    payload = read_model_file(Path(path))
    cls = MODEL_CLASSES.get(str(payload["model_class"]), BaseModel)
    return cls.load(path)


def drive_train(source: str | PhysicsSource, where: str = "--model") -> DriveTrain:
    """The drive train a source names: a preset, a TOML, or the train a fitted model file
    carries (a model fitted on simulator files carries none: refused)."""
    parsed = parse_source(source, where) if isinstance(source, str) else source
    if parsed.kind == "preset":
        return DriveTrain.preset(parsed.preset)
    if parsed.kind == "config":
        return DriveTrain.from_toml(parsed.paths[0])
    if len(parsed.paths) != 1:
        raise ConfigError("a drive train comes from one model file, not a list of files",
                          where=where, fix="give one model file, preset or config:FILE.toml")  # fmt: skip
    path = parsed.paths[0]
    fitted = load_model(path)
    spec = getattr(fitted, "mechanistic_spec_", None) or {}
    if spec.get("kind") == "preset":
        return DriveTrain.preset(str(spec["name"]))
    if spec.get("kind") == "train":
        return DriveTrain.from_dict(dict(spec["spec"]), source=f"model file {path}")
    raise ConfigError(
        f"the model in this file ({type(fitted).__name__}) carries no drive train "
        f"(its physics: {spec.get('kind', 'none')})",
        source=path,
        where=where,
        fix="fit a model on a drive-train physics (fit --mechanistic preset or config:FILE.toml), "
        "or give --model preset / config:FILE.toml",
    )
