"""Common estimator machinery: parameters, validation at the boundary, save/load.

Estimators follow the scikit-learn convention: the constructor stores hyperparameters only,
``fit`` validates them and the data, fitted state ends in ``_``. A saved model is one file
written with ``torch.save`` holding only tensors and JSON-able primitives, and read back with
``torch.load(..., weights_only=True)`` (no arbitrary pickle).
"""

from __future__ import annotations

import inspect
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar, Self

import numpy as np
import pandas as pd
import torch
from torch import nn

from drafttwin import ROLLERS, __version__
from drafttwin._io import atomic_path
from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import ConfigError, DataError, DrafttwinError, ModelFileError
from drafttwin.models.mechanistic import MechanisticModel
from drafttwin.models.simulation import (
    TASK_CHECKS,
    blank_after_init,
    check_task_params,
    init_rows,
    input_matrix,
    input_names,
    is_simulation,
    output_names,
)
from drafttwin.models.training import FitProgress

FORMAT_NAME = "drafttwin-model"
FORMAT_VERSION = 1
"""Bumped whenever the layout of a model file changes incompatibly."""

MODEL_CLASSES: dict[str, type[BaseModel]] = {}
"""Estimator classes by class name (filled automatically), used to load model files."""


class NotFittedError(DrafttwinError):
    """A model was used (predict, save) before ``fit``."""


def _int_at_least(low: int) -> Callable[[Any], bool]:
    return lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= low


def _valid_device(v: Any) -> bool:
    if v == "auto":
        return True
    try:
        torch.device(v)
    except (RuntimeError, TypeError):
        return False
    return True


_CHECKS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "window": (_int_at_least(1), "an integer >= 1 (samples)"),
    "data_window": (_int_at_least(1), "an integer >= 1 (samples)"),
    "hidden": (_int_at_least(1), "an integer >= 1"),
    "data_hidden": (_int_at_least(1), "an integer >= 1"),
    "layers": (_int_at_least(1), "an integer >= 1"),
    "data_layers": (_int_at_least(1), "an integer >= 1"),
    "batch_size": (_int_at_least(1), "an integer >= 1"),
    "epochs": (_int_at_least(1), "an integer >= 1"),
    "horizon": (_int_at_least(1), "an integer >= 1 (samples ahead)"),
    "folds": (_int_at_least(2), "an integer >= 2"),
    "seed": (_int_at_least(0), "an integer >= 0"),
    "stride": (_int_at_least(1), "an integer >= 1 (use every stride-th training window)"),
    "sk_channels": (lambda v: _int_at_least(3)(v) and v % 3 == 0, "a multiple of 3"),
    "dropout": (lambda v: isinstance(v, int | float) and 0 <= v < 1, "in [0, 1)"),
    "lr": (lambda v: isinstance(v, int | float) and v > 0 and math.isfinite(v), "> 0"),
    "val_fraction": (lambda v: isinstance(v, int | float) and 0 <= v < 1, "in [0, 1)"),
    "patience": (lambda v: v is None or _int_at_least(1)(v), "None or an integer >= 1"),
    "clip_norm": (lambda v: v is None or (isinstance(v, int | float) and v > 0), "None or > 0"),
    "skip": (lambda v: isinstance(v, bool), "True or False"),
    "quiet": (lambda v: isinstance(v, bool), "True or False"),
    "use_disagreement": (lambda v: isinstance(v, bool), "True or False"),
    "device": (_valid_device, '"auto", "cpu", "cuda" or "cuda:N"'),
    **TASK_CHECKS,
}


class BaseModel:
    """Base of all drafttwin estimators (see :func:`drafttwin.models.make_model`)."""

    needs_mechanistic: ClassVar[bool] = False
    trains_networks: ClassVar[bool] = False

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

    def get_params(self) -> dict[str, Any]:
        """Hyperparameters as a dict (constructor keyword arguments)."""
        return {name: getattr(self, name) for name in self.param_names()}

    def set_params(self, **params: Any) -> Self:
        unknown = sorted(set(params) - set(self.param_names()))
        if unknown:
            raise ConfigError(
                f"unknown hyperparameter(s) {unknown} for {type(self).__name__}",
                fix=f"valid: {', '.join(self.param_names())}",
            )
        for key, value in params.items():
            setattr(self, key, value)
        return self

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"

    @property
    def name(self) -> str:
        """Registry name of this model (as in reports)."""
        raise NotImplementedError

    def _check_params(self) -> None:
        for key, value in self.get_params().items():
            check = _CHECKS.get(key)
            if check is not None and not check[0](value):
                raise ConfigError(
                    f"hyperparameter {key}={value!r} is invalid for {type(self).__name__}",
                    fix=f"{key} must be {check[1]}",
                )
        check_task_params(self)

    # ----- boundary checks -------------------------------------------------------------
    def _check_series(self, series: object) -> MeasurementSeries:
        if not isinstance(series, MeasurementSeries):
            raise DataError(
                f"expected a MeasurementSeries, got {type(series).__name__}",
                fix="read measurements with drafttwin.data.io.read_measurements(...)",
            )
        if getattr(self, "outputs", None) is None and series.values.shape[1] != len(ROLLERS):
            raise DataError(
                f"the series has {series.values.shape[1]} roller column(s) {list(series.channels)}; "
                f"the models need {len(ROLLERS)}: {', '.join(ROLLERS)}",
                fix="provide one speed column per bottom roller",
            )
        wanted = output_names(self)
        if getattr(self, "outputs", None) is not None and tuple(series.channels) != wanted:
            raise DataError(
                f"the series has output channels {list(series.channels)} but the model's outputs "
                f"are {list(wanted)}",
                fix="build the series with channels=outputs (same names, same order)",
            )
        fitted = getattr(self, "rollers_", None)
        if fitted is not None and tuple(series.channels) != tuple(fitted):
            raise DataError(
                f"the series has rollers {list(series.channels)} but the model was fitted on "
                f"{list(fitted)}",
                fix="rename or reorder the columns as during fitting",
            )
        input_matrix(series, input_names(self))  # refuses missing input channels
        return series

    def _check_fitted(self) -> None:
        if not hasattr(self, "rollers_"):
            raise NotFittedError(
                f"this {type(self).__name__} is not fitted",
                fix="call fit(training_series, ...) first, or load a saved model",
            )

    def _mechanistic(
        self, series: MeasurementSeries, mechanistic: object | None, *, fitting: bool
    ) -> tuple[np.ndarray | None, MechanisticModel | None]:
        """The mechanistic prediction on the series' grid (``None`` if not needed)."""
        if not self.needs_mechanistic:
            return None, None
        model = mechanistic
        if model is None and not fitting:
            model = MechanisticModel.from_spec(getattr(self, "mechanistic_spec_", None))
        if model is None:
            raise ConfigError(
                f"the {self.name} model needs a mechanistic prediction",
                fix="pass mechanistic=MechanisticModel(source) (a callable, a simulator output "
                "file, or MechanisticModel.from_preset('fa320a'))",
            )
        channels = output_names(self)
        if not isinstance(model, MechanisticModel):
            model = MechanisticModel(model, channels=channels)  # type: ignore[arg-type]
        if model.channels != channels:
            raise DataError(
                f"the mechanistic source {model.name!r} gives channels {list(model.channels)} "
                f"but the model predicts {list(channels)}",
                fix="build the MechanisticModel with channels=<the model's outputs>",
            )
        return model.predict(series), model

    # ----- public API ------------------------------------------------------------------
    def fit(self, series: MeasurementSeries, mechanistic: object | None = None) -> Self:
        """Fit on a training series (rpm, regular time grid). Hybrids need ``mechanistic``
        (a :class:`MechanisticModel` or any source it accepts). Returns ``self``."""
        self._check_params()
        series = self._check_series(series)
        mech, mech_model = self._mechanistic(series, mechanistic, fitting=True)
        quiet = bool(getattr(self, "quiet", True)) or not self.trains_networks
        with FitProgress(f"fit {self.name}", quiet=quiet) as progress:
            self._fit(series, mech, progress)
        self.rollers_ = tuple(series.channels)
        self.mechanistic_spec_ = None if mech_model is None else mech_model.spec()
        rate = series.sample_rate_hz
        self.sample_rate_hz_ = float(rate) if np.isfinite(rate) else None
        return self

    def predict(self, series: MeasurementSeries, mechanistic: object | None = None) -> pd.DataFrame:
        """Predictions as a labelled frame: ``time`` (s) and one column per output channel
        (plus ``record`` for a series of several records); ``frame.attrs["units"]`` holds the
        channel units. Same rows and rules as :meth:`predict_values`."""
        values = self.predict_values(series, mechanistic)
        frame = pd.DataFrame({"time": series.time_s})
        for j, name in enumerate(output_names(self)):
            frame[name] = values[:, j]
        if series.n_records > 1:
            frame["record"] = series.record_ids()
        frame.attrs["units"] = {name: series.unit(name) for name in output_names(self)}
        frame.attrs["model"] = self.name
        return frame

    def predict_values(
        self, series: MeasurementSeries, mechanistic: object | None = None
    ) -> np.ndarray:
        """Predicted speeds in rpm (or the ``outputs`` channels in their units), shape
        ``(n, channels)``. ``NaN`` where the history is too short or incomplete.

        ``task="prediction"``: row ``t`` uses measurements up to ``t - horizon`` only. Pass the
        whole record (training and test part) and score the test rows: every row's prediction
        only uses earlier measurements, so this is honest and loses no test rows.

        ``task="simulation"``: a free run over the series from its first ``init_samples``
        measured rows; every later measured output is blanked (NaN) here, before the
        mechanistic source or the model sees the series. Pass the record to simulate (e.g. the
        test record alone); rows before the end of the initialisation window are NaN.
        """
        self._check_fitted()
        series = self._check_series(series)
        if is_simulation(self):
            series = blank_after_init(series, init_rows(self))
        mech, _ = self._mechanistic(series, mechanistic, fitting=False)
        return self._predict(series, mech)

    def _fit(self, series: MeasurementSeries, mech: np.ndarray | None, progress: FitProgress):
        raise NotImplementedError

    def _predict(self, series: MeasurementSeries, mech: np.ndarray | None) -> np.ndarray:
        raise NotImplementedError

    # ----- persistence -----------------------------------------------------------------
    def _get_state(self) -> tuple[dict[str, Any], dict[str, torch.Tensor]]:
        """Fitted state: JSON-able primitives and named tensors."""
        return {}, {}

    def _set_state(self, state: dict[str, Any], tensors: dict[str, torch.Tensor]) -> None:
        """Restore what :meth:`_get_state` returned."""

    def save(self, path: str | Path) -> Path:
        """Write the fitted model to one file (weights, scalers, hyperparameters, class name,
        drafttwin version, format version); written atomically. Returns the path."""
        self._check_fitted()
        state, tensors = self._get_state()
        state = {
            "rollers": list(self.rollers_),
            "mechanistic": self.mechanistic_spec_,
            "sample_rate_hz": getattr(self, "sample_rate_hz_", None),
            **state,
        }
        payload = {
            "format": FORMAT_NAME,
            "format_version": FORMAT_VERSION,
            "drafttwin_version": __version__,
            "model_class": type(self).__name__,
            "model_name": self.name,
            "params": self.get_params(),
            "state_json": json.dumps(state, allow_nan=True),
            "tensors": {k: v.detach().cpu().contiguous() for k, v in tensors.items()},
        }
        path = Path(path)
        with atomic_path(path) as tmp:
            torch.save(payload, tmp)
        return path

    @classmethod
    def load(cls, path: str | Path) -> Self:
        """Read a model file written by :meth:`save`. Raises :class:`ModelFileError` for a file
        that is missing, not a drafttwin model, corrupt, of another format version, or holds a
        model of a different class than ``cls``."""
        path = Path(path)
        payload = read_model_file(path)
        klass = MODEL_CLASSES.get(str(payload["model_class"]))
        if klass is None or not issubclass(klass, cls):
            raise ModelFileError(
                f"the file holds a {payload['model_class']}, not a {cls.__name__}",
                source=path,
                fix="load it with drafttwin.models.load_model(path)",
            )
        try:
            model = klass(**payload["params"])
            state = json.loads(payload["state_json"])
            model.rollers_ = tuple(state.pop("rollers"))
            model.mechanistic_spec_ = state.pop("mechanistic")
            model.sample_rate_hz_ = state.pop("sample_rate_hz", None)
            model._set_state(state, payload["tensors"])
        except (TypeError, KeyError, ValueError, RuntimeError) as exc:
            raise ModelFileError(
                f"the model file is damaged or inconsistent ({type(exc).__name__}: {exc})",
                source=path,
                fix="re-fit and save the model again",
            ) from exc
        return model  # type: ignore[return-value]


_REQUIRED = ("format_version", "model_class", "params", "state_json", "tensors")


def read_model_file(path: Path) -> dict[str, Any]:
    """The raw payload of a model file, checked for format and version."""
    if not path.is_file():
        raise ModelFileError("file not found", source=path, fix="check the model path")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for foreign or truncated files
        raise ModelFileError(
            f"not a readable drafttwin model file ({type(exc).__name__})",
            source=path,
            fix="pass a file written by drafttwin (model.save / drafttwin fit); it may be "
            "truncated or another program's file",
        ) from exc
    if not isinstance(payload, dict) or payload.get("format") != FORMAT_NAME:
        raise ModelFileError(
            "not a drafttwin model (no drafttwin format marker)",
            source=path,
            fix="pass a file written by drafttwin (model.save / drafttwin fit)",
        )
    if payload.get("format_version") != FORMAT_VERSION:
        raise ModelFileError(
            f"model format version {payload.get('format_version')!r} (written by drafttwin "
            f"{payload.get('drafttwin_version', '?')}); this drafttwin "
            f"({__version__}) reads version {FORMAT_VERSION}",
            source=path,
            fix="re-fit the model with this drafttwin version, or use the version that wrote it",
        )
    missing = [k for k in _REQUIRED if k not in payload]
    if missing:
        raise ModelFileError(
            f"the model file lacks {missing}", source=path, fix="re-fit and save the model again"
        )
    return payload


def pack_module(prefix: str, module: nn.Module) -> dict[str, torch.Tensor]:
    """A module's state dict with ``prefix.`` prepended to the keys."""
    return {f"{prefix}.{k}": v for k, v in module.state_dict().items()}


def unpack_module(prefix: str, tensors: dict[str, torch.Tensor], module: nn.Module) -> None:
    """Load the ``prefix.*`` tensors into ``module`` (strict) and set eval mode."""
    head = f"{prefix}."
    state = {k[len(head) :]: v for k, v in tensors.items() if k.startswith(head)}
    module.load_state_dict(state, strict=True)
    module.eval()
