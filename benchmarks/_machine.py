"""Machine description and JSON writing shared by the benchmarks: the studies' own writer
(:mod:`drafttwin.studies.figures`), pointed at this folder's ``results/``."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from drafttwin.studies.figures import machine
from drafttwin.studies.figures import write_results as _write_results

RESULTS = Path(__file__).resolve().parent / "results"

__all__ = ["RESULTS", "busy", "machine", "write_results"]


def write_results(name: str, figures: list[dict[str, Any]]) -> Path:
    """Write ``{"benchmark", "date", "machine", "figures": [...]}`` to results/<name>.json."""
    return _write_results(name, figures, RESULTS)


@contextmanager
def busy(n: int) -> Iterator[None]:
    """``n`` processes spinning a core each (``while True: pass``): the busy neighbours of a
    shared machine."""
    spin = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for p in spin:
            p.kill()
            p.wait()
