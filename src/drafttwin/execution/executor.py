"""Run independent tasks (sweep points, repeated tests) locally or on Ray, resumably.

``run_tasks(fn, configs, store=..., data_digest=...)`` calls ``fn(config) -> dict`` for every
configuration whose result is not yet in the store, in parallel, and writes each result to
the store as soon as it arrives. ``fn`` must be a module-level function (it is sent to worker
processes) and deterministic given its configuration (seeds belong in the configuration).
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import logging
import multiprocessing as mp
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from drafttwin.errors import DrafttwinError
from drafttwin.execution import ray_guard
from drafttwin.execution.interrupt import (
    Interrupted,
    restore_handler,
    signals_deferred,
    spawn_without_sigint,
    worker_init,
)
from drafttwin.execution.store import ResultStore, task_key

Task = Callable[[dict[str, Any]], dict[str, Any]]
Pending = list[tuple[int, dict[str, Any]]]
"""(index, configuration) of each task still to run."""
Finish = Callable[[int, dict[str, Any]], None]
EXECUTORS = ("local", "ray")
WORKERS_PER_CPU = 4
ADDRESS_TIMEOUT_S = 3.0
"""How long ``--address`` gets to accept a connection when the options are checked."""
RAY_POLL_S = 0.5
STOP_TIMEOUT_S = 5.0
"""How long stopped workers get to exit after SIGTERM before they are killed."""
PARALLEL_TASK_ENV = "DRAFTTWIN_PARALLEL_TASK"
"""Set to ``1`` in a process that runs tasks beside other worker processes: what it could run
side by side inside itself would only compete with them for the CPUs."""


def in_parallel_task() -> bool:
    """Whether this process is a worker of a parallel run (local pool or Ray)."""
    return os.environ.get(PARALLEL_TASK_ENV) == "1"


def _as_parallel_task(fn: Task, config: dict[str, Any]) -> dict[str, Any]:
    """``fn(config)`` in a worker process, marked as one (:func:`in_parallel_task`)."""
    os.environ[PARALLEL_TASK_ENV] = "1"
    return fn(config)


def _default_workers() -> int:
    return max(1, min(os.cpu_count() or 1, 8))


def max_workers() -> int:
    """The most parallel tasks accepted: more processes than this only cost memory."""
    return WORKERS_PER_CPU * (os.cpu_count() or 1)


def check_executor(executor: str, workers: int | None = None, address: str | None = None) -> None:
    """Refuse bad ``--executor``, ``--workers`` and ``--address`` values (call it before any
    expensive work: these are otherwise found only when the first tasks start)."""
    if executor not in EXECUTORS:
        raise DrafttwinError(f"unknown executor '{executor}'", where="--executor",
                             fix=f"use one of: {', '.join(EXECUTORS)}")  # fmt: skip
    if workers is not None and not 1 <= workers <= max_workers():
        raise DrafttwinError(
            f"{workers} parallel tasks is outside 1..{max_workers()} ({WORKERS_PER_CPU} per CPU "
            f"core of this machine)", where="--workers", fix=f"use --workers 1..{max_workers()}",
        )  # fmt: skip
    if address is not None and executor != "ray":
        raise DrafttwinError(f"an address is for the Ray executor, not '{executor}'",
                             where="--address", fix="add --executor ray or drop --address")  # fmt: skip
    if executor == "ray":
        _import_ray()
        if address is not None:
            _check_address(address)


def _check_address(address: str) -> None:
    """'auto' or [ray://]HOST:PORT with a server listening there."""
    if address == "auto":
        return
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit() or not 1 <= int(port) <= 65535 or " " in host:
        raise DrafttwinError(f"'{address}' is not a Ray address", where="--address",
                             fix="give HOST:PORT (e.g. 10.0.0.5:6379), ray://HOST:PORT or auto")  # fmt: skip
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=ADDRESS_TIMEOUT_S).close()
    except OSError as exc:
        raise DrafttwinError(f"no Ray cluster answers at '{address}' ({exc.strerror or exc})",
                             where="--address",
                             fix="start one with 'ray start --head' or give its HOST:PORT") from None  # fmt: skip


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
    check_executor(executor, workers, address)
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
    pool = cf.ProcessPoolExecutor(max_workers=min(workers, len(todo)), mp_context=mp.get_context("spawn"),
                                  initializer=worker_init, initargs=(os.getpid(),))  # fmt: skip
    try:
        # Python 3.11 spawns the workers in submit(). A signal that lands meanwhile waits
        # until every worker has its start-up data: raised between a worker's start and that
        # write, it left the worker to read an empty pipe (an EOFError traceback).
        with spawn_without_sigint(), signals_deferred():
            futures = {pool.submit(_as_parallel_task, fn, config): i for i, config in todo}
        for fut in cf.as_completed(futures):
            finish(futures[fut], fut.result())
    except BaseException:  # an error, Ctrl-C or SIGTERM: finished results are already stored
        stop_pool(pool)
        raise
    pool.shutdown(wait=True)


def stop_pool(pool: cf.ProcessPoolExecutor) -> None:
    """Cancel pending tasks and end the workers now: ``shutdown`` alone would wait for (or,
    with ``wait=False``, abandon) the running ones."""
    processes = list((pool._processes or {}).values())
    manager: threading.Thread | None = getattr(pool, "_executor_manager_thread", None)
    pool.shutdown(wait=False, cancel_futures=True)  # forgets the manager thread
    for p in processes:
        p.terminate()
    deadline = time.monotonic() + STOP_TIMEOUT_S
    for p in processes:
        p.join(max(0.0, deadline - time.monotonic()))
        if p.is_alive():
            p.kill()
            p.join(1.0)
    # the pool's manager thread ends when it sees the dead workers; once it has, nothing is
    # left to wake up, and Python 3.11's exit hook writing to its wake-up pipe anyway can
    # race with the pipe's closing ("Bad file descriptor", a stray traceback on stderr)
    if manager is not None:
        manager.join(STOP_TIMEOUT_S)
        if not manager.is_alive():
            getattr(cf.process, "_threads_wakeups", {}).pop(manager, None)


def _run_ray(fn: Task, todo: Pending, finish: Finish, workers: int, address: str | None) -> None:
    with ray_session(workers, address) as ray:
        remote = ray.remote(_as_parallel_task)
        pending = {remote.remote(fn, config): i for i, config in todo}
        try:
            while pending:
                with signals_deferred():  # returns every RAY_POLL_S to let a signal through
                    done, _ = ray.wait(list(pending), num_returns=1, timeout=RAY_POLL_S)
                for ref in done:
                    finish(pending.pop(ref), ray.get(ref))
        except BaseException:  # an error, Ctrl-C or SIGTERM: stop the tasks still running
            for ref in pending:
                with contextlib.suppress(Exception):
                    ray.cancel(ref, force=True)
            raise


@contextlib.contextmanager
def ray_session(cpus: int, address: str | None, *, foreground: bool = False) -> Iterator[Any]:
    """Ray for the block: the cluster at ``address``, else a private instance with ``cpus``
    CPUs, started here when none runs yet and shut down after the block (with a guard
    process that kills it if this process dies). The caller's SIGTERM handler stays (ray.init
    installs its own). ``foreground``: a private instance's workers run at the caller's
    priority, not at Ray's default niceness of 15 (the hall's twins are the work a user waits
    on: at nice 15 beside other work they fell seconds behind a `twin run` at 0)."""
    ray = _import_ray()
    started = not ray.is_initialized()
    guard = _start_guard() if started and not address else None
    sigterm = signal.getsignal(signal.SIGTERM)
    try:
        if started:
            try:
                if foreground and not address:
                    os.environ.setdefault("RAY_worker_niceness", "0")
                _init_ray(ray, cpus, address)
            except SystemExit as exc:  # Ray's own SIGTERM handler, while it starts
                if exc.code != signal.SIGTERM:
                    raise
                raise Interrupted(signal.SIGTERM, "Ray was still starting") from None
        restore_handler(signal.SIGTERM, sigterm)
        yield ray
    finally:
        if started:
            ray.shutdown()
        if guard is not None:
            guard.terminate()
            guard.wait()


def _import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise DrafttwinError(
            "Ray is not installed",
            where="--executor ray",
            fix="pip install 'drafttwin[ray]' (or use --executor local)",
        ) from None
    return ray


def _init_ray(ray: Any, workers: int, address: str | None) -> None:
    # abseil's failure signal handler, installed by Ray's core worker, answered a SIGTERM
    # during the start with a stack dump on stderr; the caller's handler answers it
    os.environ.setdefault("RAY_DISABLE_FAILURE_SIGNAL_HANDLER", "1")
    if not address:
        ray.init(num_cpus=workers, ignore_reinit_error=True, log_to_driver=False,
                 include_dashboard=False, logging_level=logging.ERROR)  # fmt: skip
        return
    try:
        ray.init(address=address, ignore_reinit_error=True, log_to_driver=False,
                 logging_level=logging.ERROR)  # fmt: skip
    except (ConnectionError, TimeoutError, ValueError) as exc:
        raise DrafttwinError(
            f"no Ray cluster at '{address}' ({str(exc).splitlines()[0][:120]})",
            where="--address",
            fix="start one with 'ray start --head' or give its HOST:PORT",
        ) from None


def _start_guard() -> subprocess.Popen[bytes]:
    """The process that kills the private Ray instance if this one dies (``ray_guard.py``)."""
    return subprocess.Popen(
        [sys.executable, "-I", ray_guard.__file__, str(os.getpid())],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        start_new_session=True,  # a Ctrl-C in the terminal must not reach it
    )  # fmt: skip
