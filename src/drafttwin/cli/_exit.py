"""A long-running command's quick exit.

A command that served until a stop (``twin run``, ``twin hall``, ``plant serve``) closes its
stores, sources and workers itself and prints its summary; what is left is the interpreter's
own teardown, whose garbage collections over PyTorch's and numba's objects took 0.7-1.8 s of
the 5 s a stop may take (2 cores, busy). Such a command calls :func:`work_done`; the console
script then runs the ``atexit`` handlers, flushes and leaves without that teardown. Commands
run in-process (tests' ``CliRunner``) never reach it.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import sys
from typing import NoReturn

_state = {"done": False}


def work_done() -> None:
    """Everything the command wrote is closed and its output printed."""
    _state["done"] = True


def quick_exit_due() -> bool:
    return _state["done"]


def not_done() -> None:
    """A fresh start (the console script runs one command; a test process may run many)."""
    _state["done"] = False


def quick_exit(code: int) -> NoReturn:
    """Run the ``atexit`` handlers (logging, multiprocessing, Ray), flush, leave."""
    run_exitfuncs = getattr(atexit, "_run_exitfuncs", None)
    if run_exitfuncs is not None:
        run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # a closed pipe: nothing more to say
            stream.flush()
    os._exit(code)


__all__ = ["not_done", "quick_exit", "quick_exit_due", "work_done"]
