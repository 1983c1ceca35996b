"""The ``drafttwin`` command line.

User errors (:class:`drafttwin.errors.DrafttwinError`) print one message and exit with code 2,
handled by the command group in :mod:`drafttwin.cli.app`; usage errors exit with click's 2.
"""

from __future__ import annotations

from drafttwin.cli.app import app

# Importing the command modules registers their commands on ``app``.
from drafttwin.cli import mechanics_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import data_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import plant_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import models_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import calibrate_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import study_cmds  # noqa: E402,F401  isort: skip
from drafttwin.cli import benchmark_cmds  # noqa: E402,F401  isort: skip


def main() -> None:
    """Console-script entry point."""
    app()


__all__ = ["app", "main"]
