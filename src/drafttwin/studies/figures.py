"""The figures file every measurement of the project writes: the studies run as
``python -m drafttwin.studies.<name>`` and the timing scripts of ``benchmarks/`` (through
``benchmarks/_machine.py``), so every measured figure reads alike, with the machine it was
measured on. Written atomically (temp file, then rename)."""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
from pathlib import Path
from typing import Any

from drafttwin._io import write_text_atomic

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
    write_text_atomic(path, json.dumps(doc, indent=2) + "\n")
    return path
