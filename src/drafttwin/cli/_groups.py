"""Option groups: a set of typer options declared once, as a dataclass, and shared by commands.

``@with_group("channels", ChannelOptions)`` replaces the command's parameter ``channels`` by
the dataclass's fields (each annotated with its ``typer.Option``), so ``--help`` lists them as
ordinary options; the command receives one ``ChannelOptions`` object.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import typing
from collections.abc import Callable
from typing import Any, TypeVar

F = TypeVar("F", bound=Callable[..., Any])


def with_group(name: str, group: type) -> Callable[[F], F]:
    """Expose the fields of dataclass ``group`` as options in place of parameter ``name``."""
    hints = typing.get_type_hints(group, include_extras=True)
    fields = [f.name for f in dataclasses.fields(group)]
    options = [
        inspect.Parameter(
            f.name, inspect.Parameter.KEYWORD_ONLY, default=f.default, annotation=hints[f.name]
        )  # fmt: skip
        for f in dataclasses.fields(group)
    ]

    def wrap(command: F) -> F:
        signature = inspect.signature(command, eval_str=True)
        params: list[inspect.Parameter] = []
        for p in signature.parameters.values():
            if p.name == name:
                params += options
            else:
                params.append(p.replace(kind=inspect.Parameter.KEYWORD_ONLY))

        @functools.wraps(command)
        def run(**kwargs: Any) -> Any:
            values = {f: kwargs.pop(f) for f in fields}
            return command(**kwargs, **{name: group(**values)})

        # a function object takes any attribute; typer reads this one as the command's signature
        run.__signature__ = signature.replace(parameters=params)  # type: ignore[attr-defined]
        run.__annotations__ = {p.name: p.annotation for p in params}
        return typing.cast(F, run)

    return wrap


def stops_cleanly(note: str) -> Callable[[F], F]:
    """A command that SIGTERM / SIGINT stops with one line (``interrupted by SIGTERM; NOTE``),
    exit 128 + signal and its temporary files removed, instead of the default death (SIGTERM:
    no cleanup) or a traceback (Ctrl-C inside numba's compiled code). Put it next to ``def``."""

    def wrap(command: F) -> F:
        @functools.wraps(command)
        def run(*args: Any, **kwargs: Any) -> Any:
            from drafttwin.execution.interrupt import stop_on_signals

            with stop_on_signals(note):
                return command(*args, **kwargs)

        return typing.cast(F, run)

    return wrap
