"""User-facing errors.

Every error a user can cause by bad input (a config, a data file, a model file, a CLI option)
is a :class:`DrafttwinError`. The CLI prints its message, without a traceback, and exits with
code 2. The message names where the problem is (file, component, row or column, field) and
what to do about it.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path


class DrafttwinError(Exception):
    """An error caused by user input; carries a complete, human-readable message.

    A library error names the *parameters* it is about, never a command-line option: its
    ``problem`` and ``fix`` may hold ``{name}`` fields filled from ``terms`` (parameter name ->
    value), and ``param`` names the parameter the whole error is about. Read as a library
    message, ``{window}`` is ``window=30`` and ``{window:name}`` is ``window``; the command line
    renders the same fields as the options the user typed (``--set window=30``,
    ``--init-samples``) with one table (``drafttwin.cli._terms``), through :meth:`render`.
    """

    exit_code = 2

    def __init__(
        self,
        problem: str,
        *,
        source: str | Path | None = None,
        where: str | None = None,
        fix: str | None = None,
        terms: Mapping[str, object] | None = None,
        param: str | None = None,
    ) -> None:
        self.template = problem
        self.fix_template = fix
        self.terms = dict(terms) if terms is not None else None
        self.param = param
        self.source = str(source) if source is not None else None
        self.where = where
        super().__init__(self.message)

    @property
    def problem(self) -> str:
        return self._fill(self.template, LIBRARY_TERMS)

    @property
    def fix(self) -> str | None:
        return None if self.fix_template is None else self._fill(self.fix_template, LIBRARY_TERMS)

    def _fill(self, text: str, renderer: TermRenderer) -> str:
        if self.terms is None:
            return text
        return text.format_map({k: _Term(k, v, renderer) for k, v in self.terms.items()})

    def render(self, renderer: TermRenderer) -> str:
        """The message with its parameters named by ``renderer`` (the CLI's: as options)."""
        where = self.where
        if where is None and self.param is not None and self.param not in (self.terms or {}):
            where = renderer.name(self.param, None)  # the fields name it otherwise
        head = ": ".join(part for part in (self.source, where) if part)
        problem = self._fill(self.template, renderer)
        text = f"{head}: {problem}" if head else problem
        if self.fix_template:
            text += f"; fix: {self._fill(self.fix_template, renderer)}"
        return text

    @property
    def message(self) -> str:
        return self.render(LIBRARY_TERMS)


class TermRenderer:
    """How an error names a parameter: ``full`` with its value (``window=30``), ``name``
    alone (``window``). The library's own; the CLI's names the options typed."""

    def full(self, name: str, value: object) -> str:
        return f"{name}={_show(value)}"

    def name(self, name: str, value: object) -> str:
        return name


def _show(value: object) -> str:
    if isinstance(value, tuple | list):
        return ",".join(str(v) for v in value)
    return str(value)


LIBRARY_TERMS = TermRenderer()
"""Parameters named as the Python API names them."""


class _Term:
    """One ``{name}`` field of an error: ``{name}`` -> full, ``{name:name}`` -> the name,
    ``{name:value}`` -> the value alone."""

    def __init__(self, name: str, value: object, renderer: TermRenderer) -> None:
        self.name, self.value, self.renderer = name, value, renderer

    def __format__(self, spec: str) -> str:
        if spec == "name":
            return self.renderer.name(self.name, self.value)
        if spec == "value":
            return _show(self.value)
        return self.renderer.full(self.name, self.value)


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
