"""Common estimator machinery: parameters, validation at the boundary, save/load.

Estimators follow the scikit-learn convention: the constructor stores hyperparameters only,
``fit`` validates them and the data, fitted state ends in ``_``. A saved model is one file
written with ``torch.save`` holding only tensors and JSON-able primitives, and read back with
``torch.load(..., weights_only=True)`` (no arbitrary pickle).
"""

from __future__ import annotations

import abc
import copy
import inspect
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar, Self

import numpy as np
import pandas as pd
import torch
from torch import nn

from drafttwin._constants import __version__
from drafttwin._io import atomic_path
from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import ConfigError, DataError, DrafttwinError, ModelFileError
from drafttwin.models.estimators import params as P
from drafttwin.models.estimators.task import Task, blank_after_init, init_rows, input_matrix
from drafttwin.models.mechanistic import MechanisticModel, as_mechanistic, describe_spec
from drafttwin.models.storage import modelfile as mf
from drafttwin.models.training import FitProgress

FORMAT_NAME = mf.FORMAT_NAME
FORMAT_VERSION = mf.FORMAT_VERSION
read_model_file = mf.read_model_file

MODEL_CLASSES: dict[str, type[BaseModel]] = {}
"""Estimator classes by class name (filled automatically), used to load model files."""


class NotFittedError(DrafttwinError):
    """A model was used (predict, save) before ``fit``."""


class BaseModel(abc.ABC):
    """Base of all drafttwin estimators (see :func:`drafttwin.models.make_model`).

    Fitted state common to all: ``channels_`` (output channel names), ``units_`` (their
    units), ``mechanistic_spec_`` (the mechanistic source, JSON), ``sample_rate_hz_`` and
    ``selection_`` (options chosen on validation data, with the scores that chose them) and
    ``provenance_`` (how it was trained: data files, split; filled by the evaluation protocol
    and the command line).
    """

    needs_mechanistic: ClassVar[bool] = False
    learns_from_mechanistic: ClassVar[bool] = True
    trains_networks: ClassVar[bool] = False
    task: Task

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if not cls.__name__.startswith("_"):
            MODEL_CLASSES[cls.__name__] = cls

    # ----- parameters -------------------------------------------------------------------
    @classmethod
    def param_names(cls) -> list[str]:
        """Constructor hyperparameter names, in signature order."""
        sig = inspect.signature(cls.__init__)
        return [p for p in sig.parameters if p != "self"]

    def _store_params(self, arguments: Mapping[str, Any]) -> None:
        """Keep every constructor argument as the attribute of its name, unchanged (checks
        happen in ``fit``): call as ``self._store_params(locals())`` from ``__init__``."""
        for name in self.param_names():
            setattr(self, name, arguments[name])

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """Hyperparameters as a dict (constructor keyword arguments). With ``deep`` (as in
        scikit-learn) also ``part__name`` for each hyperparameter of every part that is an
        estimator itself (MD-S-L's ``data_model``); ``deep=False`` gives the constructor's
        arguments only, as model files store them."""
        params = {name: getattr(self, name) for name in self.param_names()}
        if deep:
            for name, part in list(params.items()):
                if is_estimator(part):
                    params.update({f"{name}__{k}": v for k, v in part.get_params().items()})
        return params

    def set_params(self, **params: Any) -> Self:
        """Set hyperparameters, ``part__name`` on a part (scikit-learn's convention; a part
        given in the same call takes its nested names). Refuses every unknown name before
        setting anything. Returns ``self``."""
        own = {k: v for k, v in params.items() if "__" not in k}
        nested: dict[str, dict[str, Any]] = {}
        unknown = sorted(set(own) - set(self.param_names()))
        for key, value in params.items():
            name, _, sub = key.partition("__")
            if key in own:
                continue
            part: Any = own.get(name, getattr(self, name, None))
            known = name in self.param_names() and is_estimator(part)
            if not known or sub not in part.get_params():
                unknown.append(key)
            nested.setdefault(name, {})[sub] = value
        if unknown:
            raise ConfigError(
                f"unknown hyperparameter(s) {sorted(unknown)} for {type(self).__name__}",
                fix=f"valid: {', '.join(self.get_params())}",
            )
        for key, value in own.items():
            setattr(self, key, value)
        for name, sub_params in nested.items():
            getattr(self, name).set_params(**sub_params)
        return self

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params(deep=False).items())
        return f"{type(self).__name__}({args})"

    @property
    def name(self) -> str:
        """Registry name of this model (as in reports)."""
        return type(self).__name__.lower()

    def check_params(self) -> None:
        """Validate the hyperparameters as ``fit`` does, before any data are read (a
        :class:`~drafttwin.errors.ConfigError` naming the parameter)."""
        self._check_params()

    def _check_params(self) -> None:
        """Validate the hyperparameters (called by ``fit``); subclasses add their rules."""
        P.check_params(type(self).__name__, self.get_params(deep=False))

    def _refuse_for_task(self, name: str, why: str) -> None:
        """Refuse a hyperparameter that was set but means nothing for this task."""
        if getattr(self, name, None) is not None:
            raise ConfigError(
                f"{{{name}}} does not apply to {type(self).__name__} with {{task}}: {why}",
                terms={name: getattr(self, name), "task": self.task.kind},
                fix=f"leave {{{name}:name}} unset for this task",
            )

    # ----- boundary checks -------------------------------------------------------------
    def _check_series(self, series: object) -> MeasurementSeries:
        if not isinstance(series, MeasurementSeries):
            raise DataError(
                f"expected a MeasurementSeries, got {type(series).__name__}",
                fix="read measurements with drafttwin.read_measurements(...)",
            )
        fitted = getattr(self, "channels_", None)
        wanted = fitted if fitted is not None else self.task.outputs
        if wanted is not None and tuple(series.channels) != tuple(wanted):
            when = "was fitted on" if fitted is not None else "predicts"
            raise DataError(
                f"the data have output channels {list(series.channels)} but the model {when} "
                f"{list(wanted)}",
                fix="read the data with the same --outputs (same names, same order)",
            )
        if len(series) == 0:
            raise DataError("the series has no rows", fix="pass a non-empty series")
        input_matrix(series, self.task.inputs)  # refuses missing input channels
        return series

    def _check_fitted(self) -> None:
        if not hasattr(self, "channels_"):
            raise NotFittedError(
                f"this {type(self).__name__} is not fitted",
                fix="call fit(training_series, ...) first, or load a saved model",
            )

    def _mechanistic(
        self, series: MeasurementSeries, mechanistic: object | None, *, fitting: bool
    ) -> tuple[np.ndarray | None, MechanisticModel | None]:
        """The mechanistic prediction on the series' grid (``None`` if not needed, or when
        fitting a model that learns nothing from it) and its source."""
        if not self.needs_mechanistic:
            return None, None
        model = mechanistic
        if model is None and not fitting:
            spec = getattr(self, "mechanistic_spec_", None)
            model = MechanisticModel.from_spec(spec)
            if model is None and spec:
                raise ConfigError(
                    f"the {self.name} model was fitted with {describe_spec(spec)}, which the "
                    "model file does not hold",
                    fix="pass the mechanistic source again (mechanistic= / --mechanistic)",
                )
        if model is None:
            raise ConfigError(
                f"the {self.name} model needs a mechanistic prediction",
                fix="pass a mechanistic source: a preset, a drive-train file, a simulator "
                "output file or a callable (MechanisticModel / --mechanistic)",
            )
        source = as_mechanistic(model)
        if fitting and not self.learns_from_mechanistic:
            # e.g. the physics alone: nothing to fit, nothing to simulate; simulator files are
            # read through here (cheap), so one without the channel or with gaps is refused
            # now, not by a later evaluate
            if source.n_tables:
                source.predict_values(series, channels=series.channels)
            return None, source
        return source.predict_values(series, channels=series.channels), source

    def _window_lengths(self) -> list[int]:
        """The model's input windows, samples (a simulation needs as many measured rows)."""
        return [int(getattr(self, "window", 1))]

    def _init_rows(self) -> int:
        """Measured rows at the start of each record that a simulation may use."""
        return init_rows(self.task, *self._window_lengths())

    # ----- public API ------------------------------------------------------------------
    def fit(self, series: MeasurementSeries, mechanistic: object | None = None) -> Self:
        """Fit on a training series (regular time grid, one or several records). Hybrids need
        ``mechanistic`` (a :class:`MechanisticModel` or any source it accepts). Returns
        ``self``."""
        self._check_params()
        series = self._check_series(series)
        mech, mech_model = self._mechanistic(series, mechanistic, fitting=True)
        self.selection_: dict[str, Any] = {}
        self.provenance_: dict[str, Any] = {}
        quiet = bool(getattr(self, "quiet", True)) or not self.trains_networks
        with FitProgress(f"fit {self.name}", quiet=quiet) as progress:
            self._fit(series, mech, progress)
        self.channels_ = tuple(series.channels)
        self.units_ = {name: series.unit(name) for name in (*series.channels, *self.task.inputs)}
        self.mechanistic_spec_ = None if mech_model is None else mech_model.spec()
        rate = series.sample_rate_hz
        self.sample_rate_hz_ = float(rate) if np.isfinite(rate) else None
        return self

    def predict(self, series: MeasurementSeries, mechanistic: object | None = None) -> pd.DataFrame:
        """Predictions as a labelled frame: the time (s; the column named as the file named it,
        else ``time``) and one column per output channel
        (plus ``record`` for a series of several records); ``frame.attrs["units"]`` holds the
        channel units. Same rows and rules as :meth:`predict_values`."""
        values = self.predict_values(series, mechanistic)
        frame = pd.DataFrame({series.time_column: series.time_s})
        for j, name in enumerate(self.channels_):
            frame[name] = values[:, j]
        if series.n_records > 1:
            frame["record"] = series.record_ids()
        frame.attrs["units"] = {name: self.units_.get(name, "") for name in self.channels_}
        frame.attrs["model"] = self.name
        return frame

    def predict_values(
        self, series: MeasurementSeries, mechanistic: object | None = None
    ) -> np.ndarray:
        """Predicted outputs in their units, shape ``(n, channels)``; ``NaN`` where the history
        is too short or incomplete.

        Task ``prediction``: row ``T`` uses measurements up to ``T - horizon`` only. Pass the
        whole record (training and test part) and score the test rows: every row's prediction
        only uses earlier measurements, so this is honest and loses no test rows.

        Task ``simulation``: a free run over each record from its first ``init_samples``
        measured rows; every later measured output is blanked (NaN) here, before the
        mechanistic source or the model sees the series. Rows inside the initialisation
        window are NaN.
        """
        self._check_fitted()
        series = self._check_series(series)
        if self.task.simulation:
            series = blank_after_init(series, self._init_rows())
        mech, _ = self._mechanistic(series, mechanistic, fitting=False)
        return self._predict(series, mech)

    def _fit(  # noqa: B027  (an optional hook: models without state keep it empty)
        self, series: MeasurementSeries, mech: np.ndarray | None, progress: FitProgress
    ) -> None:
        """Fit the model's own state (subclasses); ``mech``: the mechanistic prediction."""

    @abc.abstractmethod
    def _predict(self, series: MeasurementSeries, mech: np.ndarray | None) -> np.ndarray:
        """Predictions ``(n, channels)`` for a checked (and, in a simulation, blanked) series."""

    # ----- persistence -----------------------------------------------------------------
    def output_range(self) -> dict[str, tuple[float, float]]:
        """Each output channel's (min, max) in the measured training data, in the data's
        units, where the model keeps it (its scaling); empty for a model that keeps none."""
        return {}

    def _get_state(self) -> tuple[dict[str, Any], dict[str, torch.Tensor]]:
        """Fitted state: JSON-able primitives and named tensors."""
        return {}, {}

    def _set_state(  # noqa: B027  (an optional hook, as _get_state)
        self, state: dict[str, Any], tensors: dict[str, torch.Tensor]
    ) -> None:
        """Restore what :meth:`_get_state` returned."""

    def save(self, path: str | Path) -> Path:
        """Write the fitted model to one file (weights, scalers, hyperparameters, class name,
        drafttwin version, format version); written atomically. Returns the path."""
        self._check_fitted()
        state, tensors = self._get_state()
        state = {**self._common_state(), **state}
        payload = {
            "format": FORMAT_NAME,
            "format_version": FORMAT_VERSION,
            "drafttwin_version": __version__,
            "model_class": type(self).__name__,
            "model_name": self.name,
            "params_json": json.dumps(
                P.encode_params(self.get_params(deep=False)), allow_nan=False
            ),
            "state_json": json.dumps(state, allow_nan=True),
            "tensors": {k: v.detach().cpu().contiguous() for k, v in tensors.items()},
        }
        payload["checksum"] = mf.checksum(payload)
        path = Path(path)
        # through a Python file object: a full disk raises OSError (named by path in the CLI),
        # not torch's RuntimeError from its own writer
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:  # noqa: PTH123
            torch.save(payload, fh)
        return path

    @classmethod
    def load(cls, path: str | Path) -> Self:
        """Read a model file written by :meth:`save`, every field checked as construction
        checks it (:mod:`drafttwin.models.storage.modelfile`). Raises :class:`ModelFileError`, naming
        the field, for a file that is missing, not a drafttwin model, corrupt, of another
        format version, holds invalid hyperparameters or state, or a model of a different
        class than ``cls``. A training device this machine lacks falls back to the CPU with a
        :class:`~drafttwin.models.storage.modelfile.DeviceFallbackWarning`."""
        path = Path(path)
        payload = read_model_file(path)
        klass = MODEL_CLASSES.get(payload["model_class"])
        if klass is None:
            raise mf.refuse(path, "model_class", f"{mf.short(payload['model_class'])} is not a "
                            "drafttwin model class")  # fmt: skip
        if not issubclass(klass, cls):
            raise ModelFileError(
                f"the file holds a {payload['model_class']}, not a {cls.__name__}",
                source=path,
                fix="load it with drafttwin.load_model(path)",
            )
        model = mf.construct(path, payload, klass, MODEL_CLASSES)
        stored_state = mf.json_field(path, payload, "state_json")
        mf.check_common_state(path, stored_state)
        model._restore(path, copy.deepcopy(stored_state), payload["tensors"])
        mf.check_restored(path, payload, stored_state, model)
        return model

    def _restore(self, path: Path, state: dict[str, Any], tensors: dict[str, torch.Tensor]) -> None:
        """Take the fitted state of a checked model file."""
        self.channels_ = tuple(state.pop("channels"))
        self.units_ = dict(state.pop("units"))
        self.mechanistic_spec_ = state.pop("mechanistic")
        self.sample_rate_hz_ = state.pop("sample_rate_hz")
        self.selection_ = dict(state.pop("selection"))
        self.provenance_ = dict(state.pop("provenance"))
        with mf.reading(path, "state"):
            self._set_state(state, tensors)

    def _common_state(self) -> dict[str, Any]:
        """The state every model file holds, as :meth:`save` writes it."""
        return {
            "channels": list(self.channels_),
            "units": dict(self.units_),
            "mechanistic": self.mechanistic_spec_,
            "sample_rate_hz": self.sample_rate_hz_,
            "selection": self.selection_,
            "provenance": self.provenance_,
        }


def is_estimator(value: object) -> bool:
    """Whether ``value`` is an estimator instance (has ``get_params``), not a class."""
    return hasattr(value, "get_params") and not isinstance(value, type)


def pack_module(prefix: str, module: nn.Module) -> dict[str, torch.Tensor]:
    """A module's state dict with ``prefix.`` prepended to the keys."""
    return {f"{prefix}.{k}": v for k, v in module.state_dict().items()}


def unpack_module(prefix: str, tensors: dict[str, torch.Tensor], module: nn.Module) -> None:
    """Load the ``prefix.*`` tensors into ``module`` (strict) and set eval mode."""
    head = f"{prefix}."
    state = {k[len(head) :]: v for k, v in tensors.items() if k.startswith(head)}
    expected = module.state_dict()
    for name in state:
        if name not in expected:
            raise mf.TensorMismatch(head + name, "is unknown (not written by drafttwin)")
    for name, wanted in expected.items():  # one clear line each, not torch's list
        if name not in state:
            raise mf.TensorMismatch(head + name, "is missing")
        if tuple(state[name].shape) != tuple(wanted.shape):
            raise mf.TensorMismatch(head + name, f"has shape {tuple(state[name].shape)}, the "
                                    f"model needs {tuple(wanted.shape)}")  # fmt: skip
    module.load_state_dict(state, strict=True)
    module.eval()
