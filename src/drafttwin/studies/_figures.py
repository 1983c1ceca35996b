"""The figures file of a study run as ``python -m drafttwin.studies.<name>``: the same JSON
document the timing scripts of ``benchmarks/`` write (``benchmarks/_machine.py``), so every
measured figure of the project reads alike, with the machine it was measured on."""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
from pathlib import Path
from typing import Any

RESULTS = Path("benchmarks") / "results"
"""Where the figures go: the repository's results folder when run from its root."""


def machine() -> dict[str, Any]:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return {
        "cpu": cpu,
        "logical_cores": os.cpu_count(),
        "python": platform.python_version(),
        "platform": platform.platform(),
    }


def write_results(name: str, figures: list[dict[str, Any]], folder: Path = RESULTS) -> Path:
    """Write ``{"benchmark": name, "date", "machine", "figures": [...]}`` to
    ``folder/<name>.json``."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.json"
    doc = {
        "benchmark": name,
        "date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "machine": machine(),
        "figures": figures,
    }
    path.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    return path
