"""Model registry: build estimators by name under a profile, and load model files."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from drafttwin.errors import ConfigError
from drafttwin.models.base import MODEL_CLASSES, BaseModel, read_model_file
from drafttwin.models.datadriven import GRUModel, LSTMModel, MechanisticBaseline, PersistenceModel
from drafttwin.models.hybrid import ParallelHybrid
from drafttwin.models.mdsl import MDSL
from drafttwin.models.profiles import PROFILES, Profile

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


def get_profile(profile: str | Profile) -> Profile:
    """A :class:`Profile` by name (``quick``, ``standard``, ``paper``) or as given."""
    if isinstance(profile, Profile):
        return profile
    if profile not in PROFILES:
        raise ConfigError(f"unknown profile {profile!r}", fix=f"use one of {', '.join(PROFILES)}")
    return PROFILES[profile]


def make_model(name: str, profile: str | Profile = "quick", **hyper: Any) -> BaseModel:
    """A new, unfitted estimator by registry name with the profile's hyperparameters,
    overridden by ``hyper`` (e.g. ``horizon=2, seed=3, quiet=True``).

    Raises :class:`ConfigError` for an unknown name, profile or hyperparameter.
    """
    key = str(name).strip().lower()
    if key not in _FACTORIES:
        raise ConfigError(f"unknown model {name!r}", fix=f"use one of {', '.join(MODEL_NAMES)}")
    cls, fixed = _FACTORIES[key]
    params = {**get_profile(profile).hyperparameters(key.removesuffix("+d")), **fixed}
    accepted = set(cls.param_names())
    params = {k: v for k, v in params.items() if k in accepted}
    unknown = sorted(set(hyper) - accepted)
    if unknown:
        raise ConfigError(
            f"unknown hyperparameter(s) {unknown} for model {key!r}",
            fix=f"valid: {', '.join(cls.param_names()) or '(none)'}",
        )
    return cls(**{**params, **hyper})


def load_model(path: str | Path) -> BaseModel:
    """Load any drafttwin model file (the class is read from the file)."""
    payload = read_model_file(Path(path))
    cls = MODEL_CLASSES.get(str(payload["model_class"]), BaseModel)
    return cls.load(path)
