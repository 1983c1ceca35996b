"""One run at a time per study folder: ``with study_lock(out): ...``.

The lock is ``OUT/.lock``, held with ``fcntl.flock`` for the whole run and holding the owner's
pid, host and start time. The kernel releases a flock when its owner dies (even by SIGKILL),
so a lock left by a dead run is free: the next run takes it over and says so. A second run
while the first is alive fails at once, naming the owner.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import os
import re
import socket
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from drafttwin.errors import DrafttwinError

LOCK_NAME = ".lock"
_TEMPORARY = re.compile(r"^\.(?P<name>.+)\.[a-z0-9_]{8}(?P<suffix>\.[^.]*)?$")
"""Names of :func:`drafttwin._io.atomic_path`'s temporary files: ``.<name>.<8 random><suffix>``."""


class StudyLocked(DrafttwinError):
    """Another live run holds the study folder."""


def _owner(lock_path: Path) -> dict[str, Any]:
    """What the lock file says about its owner (empty when unreadable)."""
    try:
        owner = json.loads(lock_path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return owner if isinstance(owner, dict) else {}


def _remove_temporaries(study_dir: Path) -> int:
    """Delete the temporary files that a killed run left mid-write (never used: a file is
    renamed into place only when complete). Only called while holding a lock taken over from a
    dead owner, so no live writer owns them. Returns how many were removed."""
    removed = 0
    for path in study_dir.rglob(".*"):
        match = _TEMPORARY.match(path.name)
        if match and path.is_file() and match["name"].endswith(match["suffix"] or ""):
            path.unlink(missing_ok=True)
            removed += 1
    return removed


def _alive(pid: object) -> bool:
    if not isinstance(pid, int) or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, another user's
        return True
    return True


@contextlib.contextmanager
def study_lock(study_dir: str | Path) -> Iterator[Path]:
    """Hold ``study_dir/.lock`` for the duration of the block.

    Raises:
        StudyLocked: another live process holds it (exit code 2 in the CLI).
    """
    import fcntl  # POSIX only; imported here so the module imports everywhere

    study_dir = Path(study_dir)
    study_dir.mkdir(parents=True, exist_ok=True)
    lock_path = study_dir / LOCK_NAME
    fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            owner = _owner(lock_path)
            raise StudyLocked(
                f"the study folder is in use by another run (pid {owner.get('pid', '?')} on "
                f"{owner.get('host', '?')}, started {owner.get('started_utc', '?')})",
                source=lock_path,
                fix="wait for that run to finish, stop it, or use another --out",
            ) from None
        previous = _owner(lock_path)
        if previous and previous.get("pid") != os.getpid():
            # the flock was free, so its owner has ended without removing the file
            state = "not running" if not _alive(previous.get("pid")) else "no longer holding it"
            removed = _remove_temporaries(study_dir)
            left = f"; removed {removed} unfinished temporary file(s)" if removed else ""
            print(f"note: taking over the stale lock {lock_path} (pid {previous.get('pid')} "
                  f"on {previous.get('host')}, {state}){left}", file=sys.stderr)  # fmt: skip
        me = {"pid": os.getpid(), "host": socket.gethostname(),
              "started_utc": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")}  # fmt: skip
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(me) + "\n").encode(), 0)
        try:
            yield lock_path
        finally:
            os.ftruncate(fd, 0)  # released cleanly: no owner left to report
    finally:
        os.close(fd)  # closing the descriptor releases the flock
