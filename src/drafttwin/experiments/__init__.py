"""Experiments: sweeps and repeated tests through a resumable executor, and the study."""

from drafttwin.experiments.executor import EXECUTORS, run_tasks
from drafttwin.experiments.store import ResultStore, data_hash, task_key

__all__ = ["EXECUTORS", "ResultStore", "data_hash", "run_tasks", "task_key"]
