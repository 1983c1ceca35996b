"""The model options of ``fit``: a new estimator from the CLI's options (``--profile``,
``--set NAME=VALUE,...``, the data description), and errors in the CLI's terms."""

from __future__ import annotations

import contextlib
import re
from collections.abc import Iterator
from typing import TYPE_CHECKING, Annotated, Any

import typer

from drafttwin.cli._data import pairs
from drafttwin.errors import ConfigError, DrafttwinError

if TYPE_CHECKING:
    from drafttwin.cli._data import Channels
    from drafttwin.models import BaseModel

SetOpt = Annotated[
    str | None,
    typer.Option(
        "--set",
        help="Hyperparameters NAME=VALUE[,...] over the profile's (e.g. window=30,patience=20; "
        "numbers, true/false, none or a word): any the profile sets (window, hidden, layers, "
        "dropout, lr, batch_size, epochs, patience, val_fraction, clip_norm, folds, skip, "
        "sk_channels, data_window, data_hidden, data_layers) and the model's own (accumulate, "
        "structure, fade, fallback, ...). A wrong name is refused with the valid ones.",
    ),
]

OPTION_OF = {
    "init_samples": "--init-samples",
    "horizon": "--horizon",
    "epochs": "--epochs",
    "seed": "--seed",
    "inputs": "--inputs",
    "outputs": "--outputs",
    "task": "--task",
    "quiet": "--quiet",
}
"""Hyperparameters with a CLI option of their own (the others go through ``--set``)."""


def parse_settings(text: str | None) -> dict[str, Any]:
    """``'window=30,patience=none,fade=strict'`` -> ``{'window': 30, 'patience': None,
    'fade': 'strict'}`` (integers, floats, true/false and none read as such)."""
    return {k: _value(v) for k, v in pairs(text, "--set", "window=30,patience=20").items()}


def _value(text: str) -> Any:
    low = text.lower()
    if low in ("true", "false"):
        return low == "true"
    if low in ("none", "null"):
        return None
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def new_model(
    name: str, *, profile: str | None, task: str | None, init: int | None, horizon: int,
    channels: Channels, seed: int | None, quiet: bool, epochs: int | None,
    settings: dict[str, Any],
) -> tuple[BaseModel, list[str]]:  # fmt: skip
    """A new estimator by registry name from the CLI's options, and notes for the user.

    ``--inputs`` describes the data: a model that takes no exogenous inputs (the physics
    alone, persistence) is built without them (the physics still reads the channels it
    maps). Training options on a model that trains nothing are noted, not refused."""
    from drafttwin.models import make_model
    from drafttwin.models.registry import model_class

    cls = model_class(name)
    accepted = set(cls.param_names())
    trains = "training" in accepted
    options: dict[str, Any] = {"task": task or "prediction"}
    notes = []
    if trains:
        options["inputs"] = channels.inputs or ()
    elif channels.inputs:
        notes.append(f"the {name} model takes no exogenous inputs: --inputs "
                     f"{','.join(channels.inputs)} only describes the data")  # fmt: skip
    if channels.outputs is not None:
        options["outputs"] = channels.outputs
    if init is not None:
        options["init_samples"] = init
    if horizon != 1:
        options["horizon"] = horizon
    training = {"--profile": profile, "--seed": seed, "--epochs": epochs}
    unused = [opt for opt, value in training.items() if value is not None]
    if trains:
        options |= {"seed": seed or 0, "quiet": quiet}
        if epochs is not None:
            options["epochs"] = epochs
    elif unused:
        notes.append(f"the {name} model trains nothing: {', '.join(unused)} ignored")
    if settings and not trains and not set(settings) & accepted:
        notes.append(f"the {name} model trains nothing: --set {','.join(settings)} ignored")
        settings = {}
    valid = setting_names(name)
    unknown = sorted(set(settings) - valid - set(OPTION_OF))
    if unknown:
        raise ConfigError(f"{', '.join(unknown)}: not a hyperparameter of the {name} model",
                          where="--set",
                          fix=f"valid --set names: {', '.join(sorted(valid))}")  # fmt: skip
    clash = sorted(set(settings) & set(OPTION_OF))
    if clash:
        raise ConfigError(f"--set {', '.join(clash)}: these have options of their own",
                          where="--set",
                          fix="use " + ", ".join(OPTION_OF[k] for k in clash))  # fmt: skip
    with cli_terms(setting_names(name), where="--set"):
        model = make_model(name, profile or "quick", **options, **settings)
        model._check_params()
    return model, notes


def setting_names(name: str) -> set[str]:
    """The names ``--set`` takes for registry model ``name``."""
    from drafttwin.models.registry import DATA_MODEL_FIELDS, TRAINING_FIELDS, model_class

    accepted = set(model_class(name).param_names()) - {"task", "training", "data_model"}
    if "training" in model_class(name).param_names():
        accepted |= set(TRAINING_FIELDS)
    if "data_model" in model_class(name).param_names():
        accepted |= set(DATA_MODEL_FIELDS)
    return accepted - set(OPTION_OF)


@contextlib.contextmanager
def cli_terms(names: set[str], where: str | None = None) -> Iterator[None]:
    """Re-raise the library's errors about hyperparameters in the CLI's terms:
    ``init_samples`` as ``--init-samples``, ``window=20`` (one of ``names``) as
    ``--set window=20`` (``where``: the option named when the error names none)."""
    try:
        yield
    except DrafttwinError as exc:
        problem = _cli_text(exc.problem, names)
        fix = None if exc.fix is None else _cli_text(exc.fix, names)
        changed = (problem, fix) != (exc.problem, exc.fix)
        if not changed and (exc.where or where is None):
            raise
        # a message now naming the options needs no prefix
        raise type(exc)(problem, source=exc.source,
                        where=exc.where or (None if changed else where), fix=fix) from None  # fmt: skip


_OPTION = re.compile(r"(?<![-\w.])(?:init_samples\b(=?)|(horizon|epochs|seed|task)=)")


def _cli_text(text: str, names: set[str]) -> str:
    """``'window=20 ...; set init_samples=20'`` -> ``'--set window=20 ...; set
    --init-samples 20'``; ``valid: a, b`` -> ``valid --set names: a, b``."""
    if names:
        pattern = r"(?<![-\w])(?:training\.)?(" + "|".join(sorted(names)) + r")=(?!=)"
        text = re.sub(pattern, r"--set \1=", text)
        text = re.sub(r"(?<![-\w])training\.(" + "|".join(sorted(names)) + r")\b",
                      r"--set \1", text)  # fmt: skip

    def option(m: re.Match[str]) -> str:
        if m.group(2):
            return OPTION_OF[m.group(2)] + " "
        return "--init-samples" + (" " if m.group(1) else "")

    text = _OPTION.sub(option, text)
    return text.replace("valid: ", "valid --set names: ")
