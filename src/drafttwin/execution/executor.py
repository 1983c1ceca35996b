"""Run independent tasks (sweep points, repeated tests) locally or on Ray, resumably.

``run_tasks(fn, configs, store=..., data_digest=...)`` calls ``fn(config) -> dict`` for every
configuration whose result is not yet in the store, in parallel, and writes each result to
the store as soon as it arrives. ``fn`` must be a module-level function (it is sent to worker
processes) and deterministic given its configuration (seeds belong in the configuration).
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing as mp
import os
from collections.abc import Callable, Sequence
from typing import Any

from drafttwin.errors import DrafttwinError
from drafttwin.execution.store import ResultStore, task_key

Task = Callable[[dict[str, Any]], dict[str, Any]]
Pending = list[tuple[int, dict[str, Any]]]
"""(index, configuration) of each task still to run."""
Finish = Callable[[int, dict[str, Any]], None]
EXECUTORS = ("local", "ray")


def _default_workers() -> int:
    return max(1, min(os.cpu_count() or 1, 8))


def run_tasks(
    fn: Task,
    configs: Sequence[dict[str, Any]],
    *,
    store: ResultStore | None = None,
    data_digest: str = "",
    executor: str = "local",
    workers: int | None = None,
    address: str | None = None,
    on_result: Callable[[int, dict[str, Any], bool], None] | None = None,
) -> list[dict[str, Any]]:
    """Results of ``fn`` for each configuration, in order.

    Args:
        store: where finished results live; tasks found there are not run again.
        data_digest: hash of the data the tasks read (part of every task's key).
        executor: ``local`` (a process pool; ``workers=1`` runs in this process) or ``ray``
            (the cluster at ``address``; without one, a private Ray instance on this machine
            with ``workers`` CPUs: Ray 2.60 removed the old serial ``local_mode``).
        on_result: called as ``on_result(index, result, cached)`` when a task finishes.
    """
    if executor not in EXECUTORS:
        raise DrafttwinError(
            f"unknown executor '{executor}'",
            where="--executor",
            fix=f"use one of: {', '.join(EXECUTORS)}",
        )
    keys = [task_key(c, data_digest) for c in configs]
    results: dict[int, dict[str, Any]] = {}
    todo = []
    for i, key in enumerate(keys):
        cached = store.fetch(key, configs[i]) if store is not None else None
        if cached is not None:  # found and checked; a damaged entry is recomputed
            results[i] = cached
            if on_result:
                on_result(i, results[i], True)
        else:
            todo.append(i)

    def finish(i: int, result: dict[str, Any]) -> None:
        results[i] = result
        if store is not None:
            store.put(keys[i], configs[i], result)
        if on_result:
            on_result(i, result, False)

    if todo:
        runner = _run_ray if executor == "ray" else _run_local
        runner(fn, [(i, configs[i]) for i in todo], finish, workers or _default_workers(), address)
    return [results[i] for i in range(len(configs))]


def _run_local(fn: Task, todo: Pending, finish: Finish, workers: int, address: str | None) -> None:
    if workers <= 1 or len(todo) == 1:
        for i, config in todo:
            finish(i, fn(config))
        return
    # spawn: worker processes must not inherit PyTorch/numba thread pools through fork
    ctx = mp.get_context("spawn")
    with cf.ProcessPoolExecutor(max_workers=min(workers, len(todo)), mp_context=ctx) as pool:
        futures = {pool.submit(fn, config): i for i, config in todo}
        for fut in cf.as_completed(futures):
            finish(futures[fut], fut.result())


def _run_ray(fn: Task, todo: Pending, finish: Finish, workers: int, address: str | None) -> None:
    try:
        import ray
    except ImportError:
        raise DrafttwinError(
            "Ray is not installed",
            where="--executor ray",
            fix="pip install 'drafttwin[ray]' (or use --executor local)",
        ) from None
    started = not ray.is_initialized()
    if started:
        if address:
            ray.init(address=address, ignore_reinit_error=True, log_to_driver=False)
        else:
            ray.init(num_cpus=workers, ignore_reinit_error=True, log_to_driver=False,
                     include_dashboard=False)  # fmt: skip
    try:
        remote = ray.remote(fn)
        pending = {remote.remote(config): i for i, config in todo}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                finish(pending.pop(ref), ray.get(ref))
    finally:
        if started:
            ray.shutdown()
