"""Module-level task functions for executor tests (worker processes import them)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from drafttwin.mechanics import DriveTrain, Signal, simulate


def supply_sweep_point(config: dict) -> dict:
    """Mean front-roller speed of the FA320A at one VFD set-point: a real, small sweep task."""
    train = DriveTrain.preset("fa320a")
    train = train.with_supply_schedule(Signal(0.0, 1.0, np.array([config["hz"], config["hz"]])))
    res = simulate(train, 0.05, output_rate_hz=100.0, settle_s=0.2)
    return {"front_rpm": float(res.roller_rpm()[:, 0].mean())}


def slow_marked_task(config: dict) -> dict:
    """Record that this configuration ran (a marker file), then take a moment."""
    marker = Path(config["marker_dir"]) / f"ran-{config['k']}-{os.getpid()}"
    marker.write_text("")
    time.sleep(config.get("sleep", 0.0))
    return {"k": config["k"], "square": config["k"] ** 2}


def parallel_task_mark(config: dict) -> dict:
    """Whether this process runs as a worker of a parallel run."""
    from drafttwin.execution.executor import in_parallel_task

    return {"k": config["k"], "parallel_task": in_parallel_task()}
