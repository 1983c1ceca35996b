"""The one table from the library's parameter names to the command line's options, and the
renderer that names them in an error as the user typed them.

Library errors name parameters (``{init_samples}``, ``{window}``: see
:class:`drafttwin.errors.DrafttwinError`); the CLI prints them as options: ``--init-samples
20`` for an option the user typed, ``--set window=30`` for a hyperparameter typed with
``--set``, and ``the profile's window (30)`` for a value the user never typed. A command says
which parameters the user typed with :func:`typed`; outside it every parameter reads as its
option."""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator

from drafttwin.errors import DrafttwinError, TermRenderer, _show

PARAM_FLAGS: dict[str, str] = {
    "data": "--data",
    "test": "--test-data",
    "mechanistic": "--mechanistic",
    "task": "--task",
    "init_samples": "--init-samples",
    "horizon": "--horizon",
    "outputs": "--outputs",
    "inputs": "--inputs",
    "train_fraction": "--train-fraction",
    "profile": "--profile",
    "seed": "--seed",
    "epochs": "--epochs",
    "quiet": "--quiet",
    "full_model": "--full-model",
    "skip_rows": "--score-from",
    "free_run_from": "--free-run-from",
    "tune": "--tune",
    "tune_budget": "--tune-budget",
    "tune_storage": "--tune-storage",
    "tune_seed": "--tune-seed",
    "tune_trials": "--tune-trials",
    "out": "--out",
    "rate_hz": "--rate",
    "time_column": "--time-column",
}
"""Parameter -> option. Every other hyperparameter is set with ``--set NAME=VALUE``."""


@contextlib.contextmanager
def typed(names: Iterable[str]) -> Iterator[None]:
    """Within: the user typed the parameters ``names`` (the others came from a profile or a
    default); an error raised here is printed so (:func:`renderer_for`)."""
    try:
        yield
    except DrafttwinError as exc:
        if getattr(exc, "typed_params", None) is None:
            exc.typed_params = frozenset(names)  # type: ignore[attr-defined]  # read below
        raise


def renderer_for(exc: DrafttwinError) -> CliTerms:
    """The renderer of an error raised in :func:`typed` (else: every parameter as typed)."""
    return CliTerms(getattr(exc, "typed_params", None))


def flag(name: str) -> str:
    """The option that sets parameter ``name`` (``--set NAME`` for a hyperparameter)."""
    return PARAM_FLAGS.get(name, f"--set {name}")


class CliTerms(TermRenderer):
    """Parameters as the options that set them; values the user never typed as what they
    are (``the profile's window (30)``). ``given``: the parameters the user typed (``None``:
    all of them)."""

    def __init__(self, given: Iterable[str] | None = None) -> None:
        self.given = None if given is None else frozenset(given)

    def _typed(self, name: str) -> bool:
        return self.given is None or name in self.given or name in ("data", "out", "mechanistic")

    def full(self, name: str, value: object) -> str:
        if name in PARAM_FLAGS:
            shown = f"{PARAM_FLAGS[name]} {_show(value)}"
            return shown if self._typed(name) else f"{shown} (the default)"
        if self._typed(name):
            return f"--set {name}={_show(value)}"
        return f"the profile's {name} ({_show(value)})"

    def name(self, name: str, value: object) -> str:
        if name in PARAM_FLAGS or self._typed(name):
            return flag(name)
        return f"the profile's {name}"


CLI_TERMS = CliTerms()
