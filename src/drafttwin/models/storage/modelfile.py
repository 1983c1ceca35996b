"""Reading a model file back: every field checked as construction checks it.

A model file (:meth:`~drafttwin.models.BaseModel.save`) is one ``torch.save`` payload of
primitives, JSON text and tensors, read with ``torch.load(weights_only=True)`` so that no
pickled code can run. Everything in it is then treated as untrusted input:

* the payload's own fields: their types, the format marker and version, no unknown field,
  and the SHA-256 checksum of its contents (a flipped bit is found, not used);
* the hyperparameters go through the estimator's constructor and ``_check_params`` (the same
  rules as a new model), and must read back exactly as stored (a missing, unknown or coerced
  hyperparameter is refused, not silently defaulted);
* the fitted state: channel names, units, the sample rate, the mechanistic source (a drive
  train is validated like a TOML file; a file source is only named, never opened), scalers
  (finite, ``max >= min``), and, after the model has taken it, the same round trip;
* the tensors: floating point, finite network weights, shapes that fit the hyperparameters.

Every problem is one :class:`~drafttwin.errors.ModelFileError` naming the file, the field and
the fix. A model trained on a device this machine lacks (``cuda``, ``mps``) runs on the CPU
with a :class:`DeviceFallbackWarning`.
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import json
import math
import warnings
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any, Protocol, TypeVar

import torch

from drafttwin._constants import __version__
from drafttwin.errors import DrafttwinError, ModelFileError


class StoredModel(Protocol):
    """What a model file builds (:class:`~drafttwin.models.estimators.base.BaseModel` is one): named
    hyperparameters checked on construction. A protocol, so that this module, which the
    base class imports, imports nothing of it."""

    def __init__(self, **params: Any) -> None: ...

    @classmethod
    def param_names(cls) -> list[str]: ...

    @property
    def name(self) -> str: ...

    def get_params(self, deep: bool = True) -> dict[str, Any]: ...

    def _check_params(self) -> None: ...


_Model = TypeVar("_Model", bound=StoredModel)

FORMAT_NAME = "drafttwin-model"
FORMAT_VERSION = 2
"""Bumped whenever the layout of a model file changes incompatibly (2: settings objects,
named channels with units, records, data-chosen options)."""

PAYLOAD_FIELDS: dict[str, type | tuple[type, ...]] = {
    "format": str,
    "format_version": int,
    "drafttwin_version": str,
    "model_class": str,
    "model_name": str,
    "params_json": str,
    "state_json": str,
    "tensors": dict,
}
"""Every field of a model file's payload and its type."""

OPTIONAL_FIELDS = {"checksum": str}
"""Fields a model file may lack: files written before drafttwin stored a checksum."""

COMMON_STATE = ("channels", "units", "mechanistic", "sample_rate_hz", "selection", "provenance")
"""State fields every model file holds (the rest belongs to the estimator class)."""

MECHANISTIC_KINDS = ("preset", "train", "file", "table", "array", "callable", "series-callable")
"""Kinds of mechanistic source a model file may record (see ``MechanisticModel.spec``)."""

REFIT = "re-fit the model and save it again (drafttwin fit); the file was damaged or edited"


class TensorMismatch(ValueError):
    """A stored tensor that does not fit the network the hyperparameters build."""

    def __init__(self, name: str, problem: str) -> None:
        super().__init__(f"tensor {name} {problem}")
        self.name, self.problem = name, problem


SHAPE_HINT = (" (the weights do not fit the hyperparameters hidden, layers, window, "
              "task inputs or the state's channels)")  # fmt: skip


class DeviceFallbackWarning(UserWarning):
    """A model file names a compute device this machine lacks; the model runs on the CPU."""


def refuse(path: Path, field: str, problem: str, fix: str = REFIT) -> ModelFileError:
    """The error for a bad ``field`` of the model file at ``path`` (raise it)."""
    return ModelFileError(problem, source=path, where=f"field {field}", fix=fix)


@contextlib.contextmanager
def reading(path: Path, field: str) -> Iterator[None]:
    """Turn any error raised while a part of the file is rebuilt into a :class:`ModelFileError`
    naming ``field`` (constructors raise ConfigError, TypeError, KeyError, ValueError...)."""
    try:
        yield
    except ModelFileError:
        raise
    except TensorMismatch as exc:
        raise refuse(path, f"tensors[{exc.name!r}]", "is damaged or inconsistent: it "
                     + exc.problem + SHAPE_HINT) from exc  # fmt: skip
    except KeyError as exc:
        raise refuse(path, field, f"the model file is damaged or inconsistent: {exc} is missing"
                     ) from exc  # fmt: skip
    except (TypeError, ValueError, RuntimeError, RecursionError, DrafttwinError) as exc:
        detail = _first_line(exc)
        if isinstance(exc, DrafttwinError):  # its problem and rule, on one line
            detail = exc.problem + (f"; {exc.fix}" if exc.fix else "")
        raise refuse(path, field, "the model file is damaged or inconsistent "
                     f"({type(exc).__name__}: {detail})") from exc  # fmt: skip


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


# ----- the payload --------------------------------------------------------------------------
def read_model_file(path: Path) -> dict[str, Any]:
    """The raw payload of a model file, its fields checked (types, format, version)."""
    if not path.is_file():
        what = "is a folder, a model file is expected" if path.is_dir() else "file not found"
        raise ModelFileError(what, source=path, fix="check the model path (a .dtm file 'drafttwin "
                             "fit' wrote)")  # fmt: skip
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
    version = payload.get("format_version")
    if type(version) is not int or version != FORMAT_VERSION:
        raise ModelFileError(
            f"model format version {version!r} (written by drafttwin "
            f"{payload.get('drafttwin_version', '?')}); this drafttwin "
            f"({__version__}) reads version {FORMAT_VERSION}",
            source=path,
            where="field format_version",
            fix="re-fit the model with this drafttwin version, or use the version that wrote it",
        )
    check_keys(path, "", {k: v for k, v in payload.items() if k not in OPTIONAL_FIELDS},
               PAYLOAD_FIELDS)  # fmt: skip
    fields = {**PAYLOAD_FIELDS, **{k: v for k, v in OPTIONAL_FIELDS.items() if k in payload}}
    for key, kind in fields.items():
        if not isinstance(payload[key], kind) or isinstance(payload[key], bool):
            raise refuse(path, key, f"is a {type(payload[key]).__name__}, not a "
                         f"{getattr(kind, '__name__', kind)}")  # fmt: skip
    check_tensors(path, payload["tensors"])
    return payload


def check_checksum(path: Path, payload: Mapping[str, Any]) -> None:
    """Refuse contents that no longer match their checksum. Checked after every field, so a
    hand-edited field is named by its own rule first; this finds the rest (a flipped bit in a
    weight, a valid-looking edit)."""
    if "checksum" in payload and payload["checksum"] != checksum(payload):
        raise refuse(path, "checksum", "the model file is damaged or inconsistent: its "
                     "contents do not match the checksum written with them (a flipped bit, "
                     "or an edit after it was written)")  # fmt: skip


def checksum(payload: Mapping[str, Any]) -> str:
    """SHA-256 of everything a model is rebuilt from (JSON text and tensor bytes)."""
    digest = hashlib.sha256()
    for key in ("model_class", "params_json", "state_json"):
        digest.update(f"{key}={payload[key]}\n".encode())
    for name in sorted(payload["tensors"]):
        tensor = payload["tensors"][name].detach().cpu().contiguous()
        digest.update(f"{name}:{tensor.dtype}:{tuple(tensor.shape)}\n".encode())
        digest.update(tensor.view(-1).view(torch.uint8).numpy().tobytes())
    return digest.hexdigest()


def check_keys(path: Path, where: str, found: Mapping[str, Any], expected: Iterable[str]) -> None:
    """Refuse a missing or an unknown key of the JSON object (or payload) at ``where``."""
    wanted = list(expected)
    prefix = f"{where}." if where else ""
    missing = [k for k in wanted if k not in found]
    if missing:
        raise refuse(path, prefix + missing[0], "is missing")
    unknown = sorted(str(k) for k in found if k not in wanted)
    if unknown:
        raise refuse(path, prefix + unknown[0], "is unknown (not written by drafttwin)")


def check_tensors(path: Path, tensors: Mapping[Any, Any]) -> None:
    """Named floating-point tensors; network weights finite (a cached prediction, such as
    MD-S-L's cross-fitted one, may hold NaN where it has no history)."""
    for name, value in tensors.items():
        field = f"tensors[{name!r}]"
        if not isinstance(name, str) or not isinstance(value, torch.Tensor):
            raise refuse(path, field, "is not a named tensor")
        if not value.is_floating_point():
            raise refuse(path, field, f"has dtype {value.dtype}, not floating point")
        if ("net." in name or name.startswith("net")) and not bool(torch.isfinite(value).all()):
            raise refuse(path, field, "holds NaN or infinite weights")


def json_field(path: Path, payload: Mapping[str, Any], key: str) -> dict[str, Any]:
    """A JSON-object field of the payload, parsed."""
    try:
        value = json.loads(payload[key])
    except (ValueError, RecursionError) as exc:
        raise refuse(path, key, f"is not valid JSON ({_first_line(exc)})") from exc
    if not isinstance(value, dict):
        raise refuse(path, key, f"holds a JSON {type(value).__name__}, not an object")
    return value


# ----- device ---------------------------------------------------------------------------
def fall_back_to_cpu(path: Path, params: dict[str, Any]) -> None:
    """Replace, in the stored hyperparameters, a training device this machine lacks by
    ``cpu`` (with one :class:`DeviceFallbackWarning`); an unknown device name is left for
    the constructor to refuse."""
    from drafttwin.models.training.compute import _valid_device, device_available

    for training in _training_settings(params):
        device = training.get("device")
        if not isinstance(device, str) or not _valid_device(device):
            continue  # not a device drafttwin trains on: Training() refuses it by name
        if not device_available(device):
            warnings.warn(
                DeviceFallbackWarning(
                    f"{path.name} was saved for {device}, which this machine lacks; running on cpu"
                ),
                stacklevel=3,
            )
            training["device"] = "cpu"


def _training_settings(value: Any) -> Iterator[dict[str, Any]]:
    """Every encoded Training object inside the stored hyperparameters."""
    if isinstance(value, dict):
        inner = value.get("__training__")
        if isinstance(inner, dict):
            yield inner
        for item in value.values():
            yield from _training_settings(item)


# ----- the fitted state -----------------------------------------------------------------
def check_common_state(path: Path, state: dict[str, Any]) -> None:
    """The state fields every model holds: present, of the right kind, plausible."""
    for key in COMMON_STATE:
        if key not in state:
            raise refuse(path, f"state.{key}", "is missing")
    channels = state["channels"]
    if (not isinstance(channels, list) or not channels
            or not all(isinstance(c, str) and c for c in channels)
            or len(set(channels)) != len(channels)):  # fmt: skip
        raise refuse(path, "state.channels", f"{channels!r} is not a list of distinct names")
    units = state["units"]
    if not isinstance(units, dict) or not all(isinstance(u, str) for u in units.values()):
        raise refuse(path, "state.units", f"{units!r} is not an object of unit names")
    rate = state["sample_rate_hz"]
    if rate is not None and not (_is_real(rate) and 0 < rate < math.inf):
        raise refuse(path, "state.sample_rate_hz", f"{rate!r} is not a rate > 0 (Hz) or null")
    for key in ("selection", "provenance"):
        if not isinstance(state[key], dict):
            raise refuse(path, f"state.{key}", f"is a JSON {type(state[key]).__name__}, "
                         "not an object")  # fmt: skip
    check_mechanistic_spec(path, state["mechanistic"])


def check_mechanistic_spec(path: Path, spec: Any) -> None:
    """A recorded mechanistic source: a known kind with well-formed contents. A file source
    keeps only the names of its files (shown in messages, never opened: predict asks for the
    source again)."""
    field = "state.mechanistic"
    if spec is None:
        return
    if not isinstance(spec, dict) or spec.get("kind") not in MECHANISTIC_KINDS:
        raise refuse(path, field, f"{short(spec)} is not a mechanistic source drafttwin "
                     f"records (kinds: {', '.join(MECHANISTIC_KINDS)})")  # fmt: skip
    kind = spec["kind"]
    allowed = {"preset": ("name",), "train": ("name", "source", "spec"),
               "file": ("paths",)}.get(kind, ())  # fmt: skip
    optional = ("cutoff_hz",) if kind in ("preset", "train") else ()  # a reduced train's
    check_keys(path, field, {k: v for k, v in spec.items() if k not in ("kind", *optional)},
               allowed)  # fmt: skip
    if "cutoff_hz" in spec and not (_is_real(spec["cutoff_hz"]) and spec["cutoff_hz"] > 0):
        raise refuse(path, f"{field}.cutoff_hz", f"{short(spec['cutoff_hz'])} is not a positive "
                     "frequency (Hz)")  # fmt: skip
    if kind == "file":
        paths = spec["paths"]
        if not isinstance(paths, list) or not all(isinstance(p, str) and p for p in paths):
            raise refuse(path, f"{field}.paths", "is not a list of file names")
    elif kind in ("preset", "train"):
        if not isinstance(spec["name"], str) or not isinstance(spec.get("source", ""), str):
            raise refuse(path, f"{field}.name", "is not a name")
        from drafttwin.models.mechanistic import MechanisticModel

        with reading(path, field if kind == "preset" else f"{field}.spec"):
            MechanisticModel.from_spec(spec)  # a preset must exist; a train is validated


def short(value: Any) -> str:
    """``repr(value)`` cut to 60 characters (a message names a damaged value, not all of it)."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _is_real(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


# ----- the model -----------------------------------------------------------------------
def construct(
    path: Path, payload: Mapping[str, Any], klass: type[_Model], classes: Mapping[str, type]
) -> _Model:
    """The estimator the stored hyperparameters build, through its constructor and checks
    (as a new model), after the device fallback; they must read back exactly as stored."""
    from drafttwin.models.estimators import params as P

    stored = json_field(path, payload, "params_json")
    fall_back_to_cpu(path, stored)
    names = klass.param_names()
    stored.update({k: v for k, v in P.ADDED_LATER.items() if k in names and k not in stored})
    check_keys(path, "params", stored, names)
    invalid = P.first_invalid(stored)
    if invalid is not None:
        name, rule = invalid
        raise refuse(path, f"params.{name}", f"{name}={stored[name]!r} is invalid: {name} must "
                     f"be {rule}")  # fmt: skip
    decoded = {}
    for key, value in copy.deepcopy(stored).items():
        with reading(path, f"params.{key}"):
            decoded[key] = P.decode(value, classes)
    with reading(path, "params"):
        model = klass(**decoded)
        model._check_params()
    check_round_trip(path, "params", stored, P.encode_params(model.get_params(deep=False)))
    if payload["model_name"] != model.name:
        raise refuse(path, "model_class", f"{klass.__name__} does not match the field "
                     f"model_name {short(payload['model_name'])} (a {klass.__name__} is named "
                     f"{model.name!r})")  # fmt: skip
    return model


def check_restored(path: Path, payload: Mapping[str, Any], stored_state: dict[str, Any],
                   model: Any) -> None:  # fmt: skip
    """After the model took its state: outputs agree with the channels, state and tensors
    read back as stored, and the checksum matches."""
    outputs = model.task.outputs
    if outputs is not None and tuple(outputs) != model.channels_:
        raise refuse(path, "params.task.outputs", f"{list(outputs)} differ from the channels "
                     f"the model was fitted on, {list(model.channels_)}")  # fmt: skip
    state, tensors = model._get_state()
    common = {k: stored_state[k] for k in COMMON_STATE}
    own = {k: v for k, v in stored_state.items() if k not in COMMON_STATE}
    check_round_trip(path, "state", own, json.loads(json.dumps(state)))
    check_round_trip(path, "state", common, model._common_state())
    check_tensor_round_trip(path, payload["tensors"], tensors)
    check_checksum(path, payload)


# ----- round trip ---------------------------------------------------------------------------
def check_round_trip(path: Path, where: str, stored: Any, rebuilt: Any) -> None:
    """Refuse a file whose ``stored`` field does not read back as the rebuilt model writes
    it (a missing key filled with a default, an unknown key nothing reads, a value coerced)."""
    problem = first_difference(stored, rebuilt, where)
    if problem is not None:
        raise refuse(path, *problem)


def first_difference(stored: Any, rebuilt: Any, where: str) -> tuple[str, str] | None:
    """``(field, problem)`` for the first place where two JSON values differ, else ``None``."""
    if isinstance(stored, dict) and isinstance(rebuilt, dict):
        for key in stored:
            if key not in rebuilt:
                return f"{where}.{key}", "is unknown (not written by drafttwin)"
        for key in rebuilt:
            if key not in stored:
                return f"{where}.{key}", "is missing"
            found = first_difference(stored[key], rebuilt[key], f"{where}.{key}")
            if found is not None:
                return found
        return None
    if isinstance(stored, list) and isinstance(rebuilt, list) and len(stored) == len(rebuilt):
        for k, (a, b) in enumerate(zip(stored, rebuilt, strict=True)):
            found = first_difference(a, b, f"{where}[{k}]")
            if found is not None:
                return found
        return None
    if _same_scalar(stored, rebuilt):
        return None
    return where, f"{short(stored)} is not valid here (it reads back as {short(rebuilt)})"


def _same_scalar(a: Any, b: Any) -> bool:
    if isinstance(a, bool) or isinstance(b, bool):
        return type(a) is type(b) and a == b
    if _is_number(a) and _is_number(b):
        return a == b or (math.isnan(a) and math.isnan(b))
    return type(a) is type(b) and not isinstance(a, dict | list) and a == b


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def check_tensor_round_trip(
    path: Path, stored: Mapping[str, torch.Tensor], rebuilt: Mapping[str, torch.Tensor]
) -> None:
    """The file holds exactly the tensors the model has, each of the model's shape."""
    for name in stored:
        if name not in rebuilt:
            raise refuse(path, f"tensors[{name!r}]", "is unknown (not written by drafttwin)")
    for name, value in rebuilt.items():
        if name not in stored:
            raise refuse(path, f"tensors[{name!r}]", "is missing")
        if tuple(stored[name].shape) != tuple(value.shape):
            raise refuse(path, f"tensors[{name!r}]", f"has shape {tuple(stored[name].shape)}, "
                         f"the model needs {tuple(value.shape)}{SHAPE_HINT}")  # fmt: skip


__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "DeviceFallbackWarning",
    "check_common_state",
    "check_round_trip",
    "check_tensor_round_trip",
    "fall_back_to_cpu",
    "read_model_file",
]
