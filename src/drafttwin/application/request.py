"""A fit, as one typed request: what the library's ``dt.fit`` and the ``drafttwin fit``
command both build, and the estimator it makes.

Every default lives with the thing it is a default of (the profile in
:data:`~drafttwin.models.profiles.DEFAULT_PROFILE`, the split in
:data:`~drafttwin.data.preprocessing.DEFAULT_TRAIN_FRACTION`, the physics in
:mod:`drafttwin.application.physics`, the tuning budget in
:data:`~drafttwin.application.tuning.DEFAULT_BUDGET_MIN`); a field left ``None`` takes it,
and only what the caller set is named in an error (:meth:`FitRequest.given`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from drafttwin.errors import ConfigError
from drafttwin.models import BaseModel, make_model
from drafttwin.models.profiles import DEFAULT_PROFILE
from drafttwin.models.registry import DATA_MODEL_FIELDS, TRAINING_FIELDS, get_profile, model_class

if TYPE_CHECKING:
    from drafttwin.data.series import MeasurementSeries

OWN_PARAMETERS = ("init_samples", "horizon", "epochs", "seed", "inputs", "outputs", "task",
                  "quiet")  # fmt: skip
"""Hyperparameters that are fields of the request itself (not ``settings``)."""

WINDOWS = ("window", "data_window")
"""The windows that follow ``init_samples`` in a simulation when the caller set none."""


class FitNote(UserWarning):
    """A :class:`Note` of a fit, as :func:`drafttwin.fit` raises it (``drafttwin fit`` prints
    it as ``note: ...``)."""


@dataclass(frozen=True)
class Note:
    """Something the fit did that the caller should know: a ``{name}`` template and its
    parameters (rendered like an error's, :class:`~drafttwin.errors.DrafttwinError`)."""

    text: str
    terms: Mapping[str, object] = field(default_factory=dict)

    def render(self, renderer: Any = None) -> str:
        from drafttwin.errors import LIBRARY_TERMS, ConfigError

        return ConfigError(self.text, terms=dict(self.terms)).render(renderer or LIBRARY_TERMS)


@dataclass(frozen=True)
class FitRequest:
    """Everything a fit needs. ``None`` means "the default" (and is not named in errors).

    Attributes:
        model: registry name (``parallel``, ``md-s-l``, ...) or an unfitted estimator (its own
            hyperparameters; profile, settings and task fields must then stay unset).
        data: the training records (all of them with ``test``, else split chronologically).
        test: separate test records, scored at once.
        mechanistic: the physics (a source, or its command-line text); ``None``: see
            :mod:`drafttwin.application.physics`.
        profile: ``quick`` | ``standard`` | ``paper``. settings: hyperparameters over the
            profile's (``window``, ``hidden``, ``data_hidden``, ``lr``, ``patience``, ...).
        task / init_samples / horizon / seed / epochs: as :func:`drafttwin.make_model`.
        inputs: the data's exogenous input channels the networks see (default none).
        train_fraction: chronological share of ``data`` that trains (no ``test``).
        full_model: simulate the full drive train instead of the reduced one.
        tune / tune_budget / tune_seed / tune_trials / tune_storage: search the
            hyperparameters on validation data within ``tune_budget`` CPU-minutes (and at
            most ``tune_trials`` trials), its journal in ``tune_storage`` (resumable)
            (:mod:`drafttwin.application.tuning`).
        data_label: how the data were named (kept in the model file's provenance).
        quiet: no progress bars.
    """

    model: str | BaseModel
    data: MeasurementSeries | None = None
    test: MeasurementSeries | None = None
    mechanistic: object | None = None
    profile: str | None = None
    settings: Mapping[str, Any] = field(default_factory=dict)
    task: str | None = None
    init_samples: int | None = None
    horizon: int | None = None
    inputs: tuple[str, ...] | None = None
    seed: int | None = None
    epochs: int | None = None
    train_fraction: float | None = None
    full_model: bool = False
    tune: bool = False
    tune_budget: float | None = None
    tune_seed: int | None = None
    tune_trials: int | None = None
    tune_storage: Path | None = None
    data_label: str | None = None
    quiet: bool = True

    def replace(self, **changes: Any) -> FitRequest:
        return dataclasses.replace(self, **changes)

    def given(self) -> set[str]:
        """The parameters the caller set (the rest are defaults): named in errors as typed."""
        out = {k for k in ("mechanistic", "profile", "task", "init_samples", "horizon", "inputs", "seed",
                           "epochs", "train_fraction", "tune_budget", "tune_seed", "tune_trials")
               if getattr(self, k) is not None}  # fmt: skip
        out |= {"data", "test"} | set(self.settings)
        if self.full_model:
            out.add("full_model")
        return out

    @property
    def model_name(self) -> str:
        return self.model if isinstance(self.model, str) else self.model.name


def build_model(request: FitRequest) -> tuple[BaseModel, list[Note]]:
    """A new estimator from ``request`` (the estimator given, or one by name under the
    profile), and notes for the caller. In a simulation a window the caller did not set
    follows ``init_samples`` (a profile's window longer than the measured start would be
    refused). ``inputs`` describe the data: a model that takes none is built without them."""
    if isinstance(request.model, BaseModel):
        named = [k for k in ("profile", "task", "init_samples", "horizon", "seed", "epochs")
                 if getattr(request, k) is not None] + sorted(request.settings)  # fmt: skip
        if named:
            raise ConfigError(
                f"an estimator was given with its own hyperparameters, and {', '.join(named)} too",
                fix="set them on the estimator (make_model(name, ...)), or give the model by name",
            )
        return request.model, []
    name = request.model
    cls = model_class(name)
    accepted = set(cls.param_names())
    trains = "training" in accepted
    settings = dict(request.settings)
    data = request.data
    options: dict[str, Any] = {"task": request.task or "prediction"}
    notes: list[Note] = []
    if data is not None:
        options["outputs"] = tuple(data.channels)
    if trains:
        options["inputs"] = tuple(request.inputs or ())
    elif request.inputs:
        notes.append(Note(f"the {name} model takes no exogenous inputs: {{inputs}} only "
                          "describes the data", {"inputs": request.inputs}))  # fmt: skip
    if request.init_samples is not None:
        options["init_samples"] = request.init_samples
    if request.horizon is not None and request.horizon != 1:
        options["horizon"] = request.horizon
    unused = {k: getattr(request, k) for k in ("profile", "seed", "epochs")
              if getattr(request, k) is not None}  # fmt: skip
    if trains:
        options |= {"seed": request.seed or 0, "quiet": request.quiet}
        if request.epochs is not None:
            options["epochs"] = request.epochs
    elif unused:
        fields = ", ".join(f"{{{k}:name}}" for k in unused)
        notes.append(Note(f"the {name} model trains nothing: {fields} ignored", unused))
    if settings and not trains and not set(settings) & accepted:
        fields = ", ".join(f"{{{k}:name}}" for k in settings)
        notes.append(Note(f"the {name} model trains nothing: {fields} ignored", settings))
        settings = {}
    valid = setting_names(name)
    unknown = sorted(set(settings) - valid - set(OWN_PARAMETERS))
    if unknown:
        raise ConfigError(f"{', '.join(unknown)}: not a hyperparameter of the {name} model",
                          param=unknown[0],
                          fix=f"valid hyperparameters: {', '.join(sorted(valid))}")  # fmt: skip
    clash = sorted(set(settings) & set(OWN_PARAMETERS))
    if clash:
        raise ConfigError(
            f"{', '.join(clash)} cannot be given among the hyperparameters: "
            + ("it is a parameter" if len(clash) == 1 else "each is a parameter") + " of its own",
            terms={k: settings[k] for k in clash},
            fix="give " + ", ".join(f"{{{k}:name}} {settings[k]}" for k in clash) + " instead",
        )  # fmt: skip
    profile = get_profile(request.profile or DEFAULT_PROFILE)
    if trains and options["task"] == "simulation" and request.init_samples is not None:
        notes += _follow_init(name, profile, request.init_samples, settings, accepted)
    model = make_model(name, profile, **options, **settings)
    model.check_params()
    return model, notes


def _follow_init(
    name: str, profile: Any, init: int, settings: dict[str, Any], accepted: set[str]
) -> list[Note]:
    """Windows the caller did not set, shortened to ``init`` measured rows where the
    profile's are longer (set in ``settings``); a note for each."""
    notes = []
    own = {"window": profile.window}
    if "data_model" in accepted:
        own["data_window"] = profile.window
    for key, value in own.items():
        if key not in settings and value > init:
            settings[key] = init
            notes.append(Note(f"the profile's {key} ({value}) is longer than {{init_samples}} "
                              f"measured rows: {key} follows it ({init})",
                              {"init_samples": init}))  # fmt: skip
    return notes


def setting_names(name: str) -> set[str]:
    """The hyperparameters ``settings`` may hold for registry model ``name``."""
    cls = model_class(name)
    accepted = set(cls.param_names()) - {"task", "training", "data_model"}
    if "training" in cls.param_names():
        accepted |= set(TRAINING_FIELDS)
    if "data_model" in cls.param_names():
        accepted |= set(DATA_MODEL_FIELDS)
    return accepted - set(OWN_PARAMETERS)
