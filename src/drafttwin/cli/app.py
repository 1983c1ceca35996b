"""The typer application object and shared CLI helpers.

Command modules (``cli/mechanics_cmds.py``, ``cli/data_cmds.py``, ...) import :data:`app` and
register their commands on it; ``cli/__init__.py`` imports them all.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

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

err_console = Console(stderr=True)


class _UserErrorsExit2(typer.core.TyperGroup):
    """Print a user error (:class:`DrafttwinError`) as one message and exit with its code."""

    def invoke(self, ctx):  # a typer (vendored click) Context
        from drafttwin.errors import DrafttwinError

        try:
            return super().invoke(ctx)
        except DrafttwinError as exc:
            from rich.markup import escape

            err_console.print(
                f"[bold red]error:[/] {escape(exc.message)}", highlight=False, soft_wrap=True
            )
            raise typer.Exit(exc.exit_code) from None
        except KeyboardInterrupt:  # Ctrl-C outside a study's own handling: no traceback
            err_console.print("interrupted", highlight=False)
            raise typer.Exit(130) from None


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
