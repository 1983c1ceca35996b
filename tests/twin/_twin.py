"""Shared pieces of the live-twin tests: a short plant record and a tiny hybrid fitted on it,
and a way to run the CLI in a subprocess with a timeout."""

from __future__ import annotations

import asyncio
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from drafttwin.models import MechanisticModel, make_model
from drafttwin.plant import Plant

from .._synthetic import TINY

CHANNELS = ("front", "second", "third", "back")


def plant_record(folder: Path, duration_s: float = 6.0, seed: int = 1) -> Path:
    """A plant file with a speed change (what 'drafttwin generate' writes)."""
    rec = Plant().run(duration_s, 100.0, seed=seed, scenario="speed-change")
    path = folder / "plant.parquet"
    rec.write(path)
    return path


def tiny_hybrid(folder: Path, record: Path) -> Path:
    """A parallel hybrid (preset physics + tiny GRU on the residual) saved as a model file."""
    from drafttwin.data.io import read_measurements

    series = read_measurements(record)
    model = make_model("parallel", **TINY).fit(series, MechanisticModel.from_preset("fa320a"))
    path = folder / "tiny.dtm"
    model.save(path)
    return path


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def serve_beside(service: Any, port: int, seconds: float, load: Callable[[Any], None],
                 join_s: float = 60.0) -> None:  # fmt: skip
    """Run ``service`` with its page on 127.0.0.1:``port`` for at most ``seconds``, and
    ``load(page)`` in a thread once the page listens (it ends the run with ``service.stop()``)."""
    from drafttwin.twin.web.server import serve_with

    pages: list[Any] = []

    def run_load() -> None:
        deadline = time.monotonic() + join_s
        while not pages and time.monotonic() < deadline:
            time.sleep(0.02)
        if pages:
            load(pages[0])

    clients = threading.Thread(target=run_load)
    clients.start()
    try:
        asyncio.run(serve_with(service, ("127.0.0.1", port), None, seconds, None, pages.append))
    finally:
        clients.join(timeout=join_s)


def env() -> dict[str, str]:
    src = str(Path(__file__).resolve().parents[2] / "src")
    return {**os.environ, "PYTHONPATH": src, "OMP_NUM_THREADS": "1"}


def cli(*args: str) -> list[str]:
    return [sys.executable, "-c", "from drafttwin.cli import main; main()", *args]


def run_cli(*args: str, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cli(*args), env=env(), capture_output=True, text=True,
                          timeout=timeout, check=False)  # fmt: skip


def read_plant(path: Path) -> pd.DataFrame:
    frame = pd.read_parquet(path)
    frame["ts_us"] = np.round(frame["time"].to_numpy() * 1e6).astype(np.int64)
    return frame
