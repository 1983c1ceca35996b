"""Kill the processes a parent started (a private Ray instance) when the parent dies.

A private Ray instance (``ray.init()`` without an address) runs a GCS server, a raylet, agents
and worker processes under the driver. ``ray.shutdown()`` ends them, but a driver killed with
SIGKILL cannot call it, and its Ray processes then linger for a minute or more. The executor
starts this file as a separate process (``python -I ray_guard.py PARENT_PID``, in a session of
its own so that a Ctrl-C in the terminal does not reach it): it records every descendant of the
parent while the parent lives and, once the parent is gone, kills those still running (the same
process, checked by its start time, not a reused pid) and whatever they started meanwhile.

Linux only (it reads /proc); elsewhere it exits at once and Ray's own clean-up applies. It is
a standalone script (standard library only) so that it starts in milliseconds.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

POLL_S = 0.2
"""How often the parent's process tree is read (a process started and orphaned within one
interval is found through its recorded parent instead)."""
PROC = Path("/proc")


def _stat(pid: int) -> tuple[int, str] | None:
    """(parent pid, start time in clock ticks) of a live process; None if gone or a zombie."""
    try:
        fields = (PROC / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    if fields[0] in ("Z", "X"):
        return None
    return int(fields[1]), fields[19]


def _children() -> dict[int, list[int]]:
    kids: dict[int, list[int]] = {}
    for entry in PROC.iterdir():
        if entry.name.isdigit() and (st := _stat(int(entry.name))) is not None:
            kids.setdefault(st[0], []).append(int(entry.name))
    return kids


def _descendants(roots: list[int]) -> dict[int, str]:
    """Every live process below ``roots``, with its start time."""
    kids, found, todo = _children(), {}, list(roots)
    while todo:
        for child in kids.get(todo.pop(), []):
            if child not in found and (st := _stat(child)) is not None:
                found[child] = st[1]
                todo.append(child)
    return found


def guard(parent_pid: int) -> int:
    """Record ``parent_pid``'s descendants until it dies, then kill them; the count killed."""
    me = os.getpid()
    known: dict[int, str] = {}
    while os.getppid() == parent_pid:
        known.update(_descendants([parent_pid]))
        time.sleep(POLL_S)
    killed = 0
    for _ in range(5):  # what the recorded processes started in the meantime, then again
        known.update(_descendants(list(known)))
        alive = [p for p, t in known.items() if p != me and (st := _stat(p)) and st[1] == t]
        if not alive:
            break
        for pid in alive:
            try:
                os.kill(pid, signal.SIGKILL)
                killed += 1
            except OSError:
                pass
        time.sleep(POLL_S)
    return killed


def main(argv: list[str]) -> int:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if len(argv) != 2 or not PROC.is_dir():
        return 0
    guard(int(argv[1]))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
