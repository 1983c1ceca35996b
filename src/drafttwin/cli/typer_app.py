"""The typer application object and shared CLI helpers.

Command modules (``cli/mechanics_cmds.py``, ``cli/data_cmds.py``, ...) import :data:`app` and
register their commands on it; ``cli/__init__.py`` imports them all.
"""

from __future__ import annotations

import contextlib
import errno
import inspect
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import typer
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

if TYPE_CHECKING:
    from typer._click.core import Context  # the Context click's Group.invoke is typed with

err_console = Console(stderr=True)


def print_error(message: str) -> None:
    """``error: MESSAGE`` on stderr (the one message of a refused command)."""
    from rich.markup import escape

    err_console.print(f"[bold red]error:[/] {escape(message)}", highlight=False, soft_wrap=True)


class _UserErrorsExit2(typer.core.TyperGroup):
    """Print a user error as one message and exit with code 2: a :class:`DrafttwinError`,
    an OSError (permission, disk full, read-only, a folder for a file, ...: named by path and
    option, see :mod:`drafttwin.cli._oserrors`) and a bad option value or usage (one line
    instead of click's box)."""

    def invoke(self, ctx: Context) -> Any:
        from typer._click.exceptions import ClickException, NoArgsIsHelpError

        from drafttwin.cli._oserrors import describe, forget_paths
        from drafttwin.errors import DrafttwinError

        forget_paths()  # the options of an earlier command run in this process
        try:
            return super().invoke(ctx)
        except DrafttwinError as exc:
            from drafttwin.cli._terms import renderer_for

            print_error(exc.render(renderer_for(exc)))
            raise typer.Exit(exc.exit_code) from None
        except KeyboardInterrupt:  # Ctrl-C outside a study's own handling: no traceback
            err_console.print("interrupted", highlight=False)
            raise typer.Exit(130) from None
        except NoArgsIsHelpError:
            raise
        except ClickException as exc:  # a bad value, a missing option, an unknown command
            _closest_only(exc)
            where = getattr(getattr(exc, "ctx", None), "command_path", None) or ctx.command_path
            print_error(f"{exc.format_message()}{_range_hint(exc)}; fix: see '{where} --help'")
            raise typer.Exit(2) from None
        except OSError as exc:
            if exc.errno == errno.EPIPE:  # stdout closed by a pager or `head`: not an error
                raise
            print_error(describe(exc).message)
            raise typer.Exit(2) from None


def _closest_only(exc: Exception) -> None:
    """An unknown option's hint names the one closest option, and only a close one (click
    lists every option loosely like it: --units for --quiet)."""
    import difflib

    possible = getattr(exc, "possibilities", None)
    name = getattr(exc, "option_name", None)
    if possible and name:
        started = sorted(p for p in possible if p.startswith(name))[:1]
        close = difflib.get_close_matches(name, possible, n=1, cutoff=0.8)
        # only click's NoSuchOption has possibilities (checked above); set on any exception
        exc.possibilities = started or close  # type: ignore[attr-defined]


def _range_hint(exc: Exception) -> str:
    """' (--seed must be >= 0 and <= ...)' for a bad value of a bounded numeric option."""
    from drafttwin.cli._bounds import range_of

    opts = getattr(getattr(exc, "param", None), "opts", None) or [""]
    text = range_of(opts[0])
    return f" ({opts[0]} {text})" if text else ""


app = typer.Typer(
    name="drafttwin",
    cls=_UserErrorsExit2,
    help=(
        "Mechanism-data hybrid models of a drawing frame's drafting section (FA320A): "
        "torsional drive-train simulation, plant emulator, GRU/LSTM and multi-model "
        "residual learning."
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

console = Console()


def print_table(table: Any) -> None:
    """A table on stdout whole: into a pipe or file at 120 columns or more (rich's 80 there
    cut names and headers to 'machi…'), in a terminal at its width."""
    (console if console.is_terminal else Console(width=max(console.width, 120))).print(table)


@contextlib.contextmanager
def progress_bar(description: str, total: float, *, quiet: bool = False) -> Iterator[Progress]:
    """A rich progress bar on stderr; ``advance`` it in the caller's units (e.g. seconds)."""
    progress = Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn() if float(total).is_integer() else TextColumn(""),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err_console,
        disable=quiet,
        transient=False,
    )
    with progress:
        progress.add_task(description, total=total)
        yield progress


def print_json(obj: Any) -> None:
    """Print ``obj`` as strict JSON on stdout (NaN and infinities as null)."""
    from drafttwin._json import dumps_strict

    typer.echo(dumps_strict(obj))


def reflow_help(typer_app: typer.Typer) -> None:
    """Join the single line breaks inside each paragraph of every command's help.

    Typer joins them in a help text's first paragraph only; rich then wraps the later
    paragraphs' source lines again at the terminal width, which leaves ragged half-lines.
    Paragraphs marked ``\\b`` (click's "keep as is") keep their breaks.
    """
    for info in typer_app.registered_commands:
        text = info.help if info.help is not None else inspect.getdoc(info.callback)
        if text:
            info.help = "\n\n".join(
                p if p.startswith("\b") else " ".join(line.strip() for line in p.splitlines())
                for p in inspect.cleandoc(text).split("\n\n")
            )
    for group in typer_app.registered_groups:
        if group.typer_instance is not None:
            reflow_help(group.typer_instance)
