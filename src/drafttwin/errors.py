"""User-facing errors.

Every error a user can cause by bad input (a config, a data file, a model file, a CLI option)
is a :class:`DrafttwinError`. The CLI prints its message, without a traceback, and exits with
code 2. The message names where the problem is (file, component, row or column, field) and
what to do about it.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path


class DrafttwinError(Exception):
    """An error caused by user input; carries a complete, human-readable message."""

    exit_code = 2

    def __init__(
        self,
        problem: str,
        *,
        source: str | Path | None = None,
        where: str | None = None,
        fix: str | None = None,
    ) -> None:
        self.problem = problem
        self.source = str(source) if source is not None else None
        self.where = where
        self.fix = fix
        super().__init__(self.message)

    @property
    def message(self) -> str:
        head = ": ".join(part for part in (self.source, self.where) if part)
        text = f"{head}: {self.problem}" if head else self.problem
        if self.fix:
            text += f"; fix: {self.fix}"
        return text


class ConfigError(DrafttwinError):
    """A drive-train or study configuration is invalid."""


class DataError(DrafttwinError):
    """A measurement file is missing, malformed or implausible."""


class RunError(DrafttwinError):
    """A process a command started for its work failed (its log says why): exit code 1."""

    exit_code = 1


class ModelFileError(DrafttwinError):
    """A saved model file is not a drafttwin model or comes from an incompatible version."""


def unknown_choice(
    problem: str,
    choices: Iterable[str],
    *,
    source: str | Path | None = None,
    where: str | None = None,
    fix_also: str = "",
) -> ConfigError:
    """The error for a name that is not one of ``choices``; its fix lists them (then
    ``fix_also``). Raise it: ``raise unknown_choice(f"unknown scenario '{name}'", ...)``."""
    return ConfigError(
        problem, source=source, where=where, fix=f"use one of: {', '.join(choices)}{fix_also}"
    )
