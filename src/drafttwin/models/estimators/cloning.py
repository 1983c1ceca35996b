"""``clone``: a new unfitted estimator with the same hyperparameters (scikit-learn's rule).

The constructor is called again with the model's own arguments (``get_params(deep=False)``):
parts that are estimators (MD-S-L's ``data_model``) are cloned the same way, every other
value (a :class:`~drafttwin.models.Task`, a :class:`~drafttwin.models.Training`, a list) is
deep-copied. Nothing fitted (the attributes ending in ``_``) and nothing shared (an MD model's
:meth:`~drafttwin.models.MDSL.use_data_model`) is carried over.
"""

from __future__ import annotations

import copy
from typing import Any, TypeVar

from drafttwin.errors import ConfigError
from drafttwin.models.estimators.base import is_estimator

M = TypeVar("M")


def clone(model: M) -> M:
    """A new unfitted estimator of ``model``'s class with equal hyperparameters, its parts
    cloned recursively. Raises :class:`ConfigError` for anything that is not an estimator
    (no ``get_params``) and for a class whose constructor changes its arguments."""
    if not is_estimator(model):
        raise ConfigError(
            f"cannot clone {model!r}: a {type(model).__name__} is not an estimator "
            "(it has no get_params)",
            fix="clone a drafttwin model (make_model(...), GRUModel(...), MDSL(...))",
        )
    cloned: M = _clone_estimator(model)
    return cloned


def _clone_estimator(model: Any) -> Any:
    args = {name: _clone_value(value) for name, value in model.get_params(deep=False).items()}
    new = type(model)(**args)
    kept = new.get_params(deep=False)
    for name, value in args.items():
        if kept.get(name) is not value:
            raise ConfigError(
                f"cannot clone {type(model).__name__}: its constructor changed {name}",
                fix="constructors must store their arguments unchanged",
            )
    return new


def _clone_value(value: Any) -> Any:
    if is_estimator(value):
        return _clone_estimator(value)
    if isinstance(value, list | tuple | set | frozenset):
        return type(value)(_clone_value(v) for v in value)
    return copy.deepcopy(value)
