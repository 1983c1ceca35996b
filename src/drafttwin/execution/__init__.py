"""Running many tasks: a resumable result store keyed by configuration and data hash, and
executors (in this process, a local process pool, or Ray) shared by the study and the
benchmarks."""

from drafttwin.execution.executor import EXECUTORS, check_executor, run_tasks
from drafttwin.execution.store import ResultStore, data_hash, task_key

__all__ = ["EXECUTORS", "check_executor", "ResultStore", "data_hash", "run_tasks", "task_key"]
