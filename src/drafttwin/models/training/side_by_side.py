"""Independent nets of one fit trained side by side, in threads.

A hybrid's fit trains nets that do not need one another's weights: the final net of each
candidate and a judge per fold (:mod:`drafttwin.models.estimators.folds`). With two CPUs or
more they train :func:`training_workers` at a time in threads: PyTorch releases the GIL inside
its operators, and two threads trained two of these nets 1.85x as fast as one after the other
on an idle 2-core machine. Each net keeps its numbers bit for bit: it trains with its own
generators (:mod:`.rng`), on one intra-op thread, with deterministic algorithms
(:func:`~drafttwin.models.training.compute.compute_context` is entered once for all);
a net that draws from PyTorch's global generator is trained alone (the caller's choice:
:func:`~drafttwin.models.training.rng.draws_global_rng`).

A job that fails stops the others at their next batch (:func:`check_cancelled`), and so does
an interruption of the thread that waits for them (Ctrl-C, or the SIGTERM handler's
exception): a stop takes one batch, not the rest of a net's training.
"""

from __future__ import annotations

import concurrent.futures as cf
import os
import threading
from collections.abc import Callable, Sequence
from typing import TypeVar

from drafttwin.errors import ConfigError
from drafttwin.execution.executor import in_parallel_task
from drafttwin.models.training.compute import training_threads

T = TypeVar("T")

WORKERS_ENV = "DRAFTTWIN_TRAINING_WORKERS"
"""Environment variable: how many nets of one fit train at a time (1-8)."""
DEFAULT_WORKERS = 2
"""Two at a time where the machine has two CPUs or more: a fit has at most two nets ready to
train side by side for most of its time (its final net and the judges that take their epochs
from it, or two candidates' final nets)."""
POLL_S = 0.1
"""How often the waiting thread looks up from the jobs (a signal's handler runs meanwhile)."""

_local = threading.local()


class Cancelled(Exception):  # noqa: N818  (a state, not an error: another job failed first)
    """A side-by-side training stopped because another one failed or the fit was stopped."""


def training_workers() -> int:
    """Nets trained at a time: ``DRAFTTWIN_TRAINING_WORKERS`` (1-8), else
    :data:`DEFAULT_WORKERS` capped by the CPUs this process may use; 1 in a worker of a
    parallel run (its siblings have the other CPUs) and where ``DRAFTTWIN_THREADS`` asks for
    intra-op threads instead."""
    text = os.environ.get(WORKERS_ENV, "").strip()
    if text:
        if not text.isdigit() or not 1 <= int(text) <= 8:
            raise ConfigError(f"{WORKERS_ENV}={text!r} is not a number of nets to train at once",
                              where=WORKERS_ENV, fix="set it to an integer from 1 to 8, or unset it")  # fmt: skip
        return int(text)
    if in_parallel_task() or training_threads() > 1:
        return 1
    try:
        cpus = len(os.sched_getaffinity(0))  # the CPUs this process may run on (Linux)
    except AttributeError:  # macOS, Windows
        cpus = os.cpu_count() or 1
    return max(1, min(DEFAULT_WORKERS, cpus))


def check_cancelled() -> None:
    """Raise :class:`Cancelled` in a side-by-side job whose run was stopped (called between
    batches)."""
    event: threading.Event | None = getattr(_local, "cancel", None)
    if event is not None and event.is_set():
        raise Cancelled


def wait_for(future: cf.Future[T]) -> T:
    """``future.result()``, looking up every :data:`POLL_S` for a stop of this job's run."""
    while True:
        check_cancelled()
        try:
            return future.result(timeout=POLL_S)
        except cf.TimeoutError:
            continue


def side_by_side(jobs: Sequence[Callable[[], T]], workers: int) -> list[T]:
    """Each job's result, in order, the jobs run ``workers`` at a time in threads (one after
    the other in this thread with ``workers`` <= 1). The first job in order that failed has its
    error raised once the others have stopped; an exception in this thread while it waits
    (an interruption) stops them too and goes on."""
    if workers <= 1 or len(jobs) <= 1:
        return [job() for job in jobs]
    cancel = threading.Event()

    def run(job: Callable[[], T]) -> T:
        _local.cancel = cancel
        try:
            return job()
        finally:
            _local.cancel = None

    pool = cf.ThreadPoolExecutor(min(workers, len(jobs)), thread_name_prefix="drafttwin-train")
    futures = [pool.submit(run, job) for job in jobs]
    try:
        while True:
            done, pending = cf.wait(futures, timeout=POLL_S, return_when=cf.FIRST_EXCEPTION)
            if not pending or any(f.exception() is not None for f in done):
                break
    except BaseException:
        cancel.set()
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    if any(f.done() and f.exception() is not None for f in futures):
        cancel.set()
    pool.shutdown(wait=True, cancel_futures=True)
    errors = [e for f in futures if not f.cancelled() and (e := f.exception()) is not None]
    if errors:  # the jobs' own errors first, not the stops they caused in the others
        raise next((e for e in errors if not isinstance(e, Cancelled)), errors[0])
    return [f.result() for f in futures]
