"""The ``drafttwin`` command line.

User errors (:class:`drafttwin.errors.DrafttwinError`), I/O errors (:mod:`drafttwin.cli._oserrors`)
and bad option values (:mod:`drafttwin.cli._bounds`) print one message and exit with code 2,
handled by the command group in :mod:`drafttwin.cli.typer_app`.
"""

from __future__ import annotations

import os
import signal
import sys
from types import FrameType


def _stopped_while_starting(signum: int, frame: FrameType | None) -> None:
    """SIGTERM or Ctrl-C before a command has its own handler (Python still importing: a
    few seconds on a busy machine): one line and exit 128 + signal, not a silent death or a
    KeyboardInterrupt traceback. Nothing has been written yet; a command that writes
    installs its own handler (``stops_cleanly``), which removes its temporaries. A worker
    process (spawned ones import this module with the command's arguments) dies as it did:
    its parent ends it with SIGTERM at a normal end, which is no news to the user."""
    mp = sys.modules.get("multiprocessing")
    if mp is not None and mp.parent_process() is not None:
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)
        return
    # the wording of a command's own stop (``execution.interrupt.Interrupted``): which of
    # the two handlers a signal meets depends on how busy the machine is, not on the user
    name = signal.Signals(signum).name
    sys.stderr.write(f"error: interrupted by {name}; nothing was written\n")
    sys.stderr.flush()
    os._exit(128 + signum)


def _run_as_the_command() -> bool:
    """Whether this process is the ``drafttwin`` script or ``python -m drafttwin`` (not a
    program that imports the CLI: its signals are its own)."""
    if "--multiprocessing-fork" in getattr(sys, "orig_argv", []):
        return False  # a spawned worker: it runs with the command's sys.argv
    argv0 = sys.argv[0] if sys.argv else ""
    return os.path.basename(argv0) == "drafttwin" or argv0.endswith(
        os.path.join("drafttwin", "__main__.py")
    )


if _run_as_the_command() and signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:
    signal.signal(signal.SIGTERM, _stopped_while_starting)
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _stopped_while_starting)

from drafttwin.cli.typer_app import app, reflow_help  # noqa: E402

# Importing the command modules registers their commands on ``app``.
from drafttwin.cli import mechanics_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import data_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import plant_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import models_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import calibrate_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import study_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import benchmark_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import faults_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import twin_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import twin_ops_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import twin_fault_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import plant_serve_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import plant_replay_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import sliver_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import sliver_read_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import sliver_level_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import leveller_cmds  # noqa: E402,F401  isort: skip

reflow_help(app)


def main() -> None:
    """Console-script entry point."""
    import signal

    # past a file-size limit (ulimit -f) a write then fails with EFBIG, reported as an
    # error, instead of SIGXFSZ killing the process with a half-written file
    if hasattr(signal, "SIGXFSZ"):
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    from drafttwin.cli._exit import not_done, quick_exit, quick_exit_due

    not_done()
    try:
        app(prog_name="drafttwin")
    except SystemExit as exc:
        if not quick_exit_due():
            raise
        quick_exit(exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 1)
    if quick_exit_due():
        quick_exit(0)


__all__ = ["app", "main"]
