"""Interrupting a run: worker processes end with their parent, signals stop the parent cleanly.

* :func:`worker_init` is the initializer of every local worker process: the worker ignores
  Ctrl-C (the parent handles it and stops the workers), asks Linux to send it SIGTERM when its
  parent dies (``PR_SET_PDEATHSIG``: a SIGKILLed parent cannot clean up) and, where that is not
  available, notices a dead parent from a watcher thread.
* :func:`stop_on_signals` turns SIGTERM and SIGINT in the parent into :class:`Interrupted`, an
  error with exit code 128 + signal and a one-line message; the executor then cancels and joins
  its workers. A second Ctrl-C while that runs stops at once. An :class:`Interrupted` that
  compiled code wrapped in a ``SystemError`` leaves the block as itself.
* :func:`spawn_without_sigint` keeps SIGINT blocked while worker processes are spawned: a
  Ctrl-C in a terminal goes to the whole process group, and a worker still importing its
  modules (before :func:`worker_init` runs) would otherwise print a traceback. The block is
  the spawning thread's only: the kernel hands a signal for the process to another thread,
  and Python still runs its handler in the main thread, so the executor also defers the
  handler's exception (:func:`signals_deferred`) until every worker is started.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import multiprocessing as mp
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from types import FrameType
from typing import Any

from drafttwin.errors import DrafttwinError

PARENT_POLL_S = 0.5
"""How often a worker without PR_SET_PDEATHSIG checks that its parent is alive."""
_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(DrafttwinError):
    """The run was stopped by a signal; finished results are kept (exit code 128 + signal)."""

    def __init__(self, signum: int, note: str = "") -> None:
        name = signal.Signals(signum).name
        super().__init__(f"interrupted by {name}" + (f"; {note}" if note else ""))
        self.signum = signum
        self.exit_code = 128 + signum


def _exit_with_parent(parent_pid: int) -> None:
    """Exit this process when ``parent_pid`` is no longer its parent (the parent died)."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)

    def watch() -> None:  # also covers a parent that died before prctl ran
        while os.getppid() == parent_pid:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="drafttwin-parent-watch", daemon=True).start()


def die_with_parent() -> Callable[[], None] | None:
    """The ``preexec_fn`` for a child command: the kernel sends the child SIGTERM when its
    parent dies, so a killed parent leaves no twin, replay or broker behind (Linux; ``None``
    elsewhere). libc is loaded here, in the parent: the child only makes one system call.
    The signal comes when the thread that started the child ends: start it from the thread
    that outlives it."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        prctl = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    return lambda: prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)


def worker_init(parent_pid: int) -> None:
    """Initializer of a worker process started by ``parent_pid`` (see the module doc)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _exit_with_parent(parent_pid)


@contextlib.contextmanager
def spawn_without_sigint() -> Iterator[None]:
    """Block SIGINT in this thread while it spawns workers; they inherit the blocked signal.

    A Ctrl-C that arrives meanwhile stays pending and is delivered to this process on exit.
    """
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _stop_now(signum: int, frame: FrameType | None = None, *, say: bool = False) -> None:
    """The second Ctrl-C: kill the worker processes and leave without any cleanup (a private
    Ray instance is ended by its guard, ``ray_guard.py``)."""
    if say:
        with contextlib.suppress(OSError):
            os.write(2, b"interrupted twice: stopped at once, finished results are kept\n")
    for child in mp.active_children():
        with contextlib.suppress(OSError):
            child.kill()
    os._exit(128 + signum)


class _Stopping:
    """What the handler of :func:`stop_on_signals` knows: the first signal, the message note,
    and whether a foreign call is running that an exception must not cross."""

    def __init__(self, note: str) -> None:
        self.note = note
        self.signum = 0
        self.deferring = 0
        self.pending = False

    def handler(self, signum: int, frame: FrameType | None) -> None:
        if self.signum and signum == signal.SIGINT:
            _stop_now(signum, say=True)
        if self.signum:  # already stopping: let the cleanup finish
            return
        self.signum = signum
        if self.deferring:
            self.pending = True  # raised when the foreign call returns
            return
        raise Interrupted(signum, self.note)


_active: list[_Stopping] = []


def _interruption_behind(exc: BaseException) -> Interrupted | None:
    """The :class:`Interrupted` in ``exc``'s chain of causes, if any."""
    seen: set[int] = set()
    cur: BaseException | None = exc
    while cur is not None and id(cur) not in seen:
        if isinstance(cur, Interrupted):
            return cur
        seen.add(id(cur))
        cur = cur.__cause__ or cur.__context__
    return None


@contextlib.contextmanager
def stop_on_signals(note: str = "") -> Iterator[None]:
    """SIGTERM and SIGINT raise :class:`Interrupted` (``note`` ends its message) in this block.

    A second SIGINT while the first is being handled stops the process at once (exit 130).
    Previous handlers come back on exit. Outside the main thread this does nothing (Python
    delivers signals to the main thread only).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    state = _Stopping(note)
    previous: dict[int, Any] = {s: signal.signal(s, state.handler) for s in _STOP_SIGNALS}
    _active.append(state)
    try:
        yield
    except SystemError as exc:
        # compiled code that was running Python when the handler raised (numba's dispatcher
        # loading a cached function) hands the interruption back as a SystemError caused by it
        stop = _interruption_behind(exc)
        if stop is None:
            raise
        raise stop from None
    finally:
        _active.remove(state)
        for s, h in previous.items():
            # once interrupted the process is on its way out: a second Ctrl-C while it
            # reports and exits ends it at once, without a KeyboardInterrupt traceback
            signal.signal(s, _stop_now if state.signum and s == signal.SIGINT else h)


@contextlib.contextmanager
def signals_deferred() -> Iterator[None]:
    """Around a call into foreign code that an exception raised by a signal handler must not
    cross (Ray's Cython ``ray.wait`` fails with a SystemError): a signal that arrives meanwhile
    raises :class:`Interrupted` when the call has returned."""
    state = _active[-1] if _active else None
    if state is None:
        yield
        return
    state.deferring += 1
    try:
        yield
    finally:
        state.deferring -= 1
    if state.pending and not state.deferring:
        state.pending = False
        raise Interrupted(state.signum, state.note)


def restore_handler(signum: int, handler: Any) -> None:
    """Put ``handler`` back for ``signum`` if a library (Ray's ``init``) replaced it."""
    if threading.current_thread() is threading.main_thread() and handler is not None:
        signal.signal(signum, handler)
