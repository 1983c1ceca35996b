"""Atomic file writing: write to a temporary file beside the target, flush it to disk, then
rename, so a reader (or a rerun after a crash or power cut) sees the old file or the whole new
one, never a part."""

from __future__ import annotations

import contextlib
import hashlib
import math
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any


@contextlib.contextmanager
def atomic_path(target: str | Path) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; rename it onto ``target`` on success.

    On any exception the temporary file is removed and ``target`` is left untouched, so a
    failed command never leaves a half-written file behind (a full disk half-way through
    included). Missing parent folders are created. An OSError about the temporary file (disk
    full, file too large, permission) is raised again about ``target``, the name the user
    gave.
    """
    target = Path(target)
    if target.exists() and not target.is_file() and not target.is_dir():
        # a device or a pipe (/dev/null, /dev/stdout): written in place; a rename would put a
        # plain file where the device was (as root: /dev/null itself)
        yield target
        return
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=target.suffix,
                                   dir=target.parent)  # fmt: skip
    except OSError as exc:
        raise _about(exc, target) from exc
    os.close(fd)
    tmp_path = Path(tmp)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp_path, 0o666 & ~umask)  # mkstemp makes 0600; give the file normal permissions
    try:
        yield tmp_path
        _fsync_file(tmp_path)  # the data reach the disk before the name points at them
        os.replace(tmp_path, target)
        _fsync_dir(target.parent)  # ... and the rename itself survives a power cut
    except OSError as exc:
        if exc.filename in (None, str(tmp_path), tmp_path):
            raise _about(exc, target) from exc
        raise
    finally:
        with contextlib.suppress(OSError):  # never hide the error that got us here
            tmp_path.unlink(missing_ok=True)


def _about(exc: OSError, target: Path) -> OSError:
    """The same error (same errno, hence the same OSError subclass) about ``target``."""
    if exc.errno is None:
        return OSError(f"{target}: {exc}")
    return OSError(exc.errno, exc.strerror or os.strerror(exc.errno), str(target))


def write_texts_atomic(files: dict[Path, str]) -> None:
    """Write several text files (UTF-8) that belong together: all are written to temporary
    files first and renamed only when every one was written, so a failure (a full disk)
    leaves all the old files as they were."""
    with contextlib.ExitStack() as stack:
        for target, text in files.items():
            stack.enter_context(atomic_path(target)).write_text(text, encoding="utf-8")


def _fsync_file(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_dir(folder: Path) -> None:
    """Flush a directory entry where the platform allows it (not on Windows)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:  # some file systems cannot sync a directory; the rename still happened
        pass
    finally:
        os.close(fd)


def write_text_atomic(target: str | Path, text: str) -> None:
    """Write ``text`` to ``target`` atomically (UTF-8)."""
    with atomic_path(target) as tmp:
        tmp.write_text(text, encoding="utf-8")


def json_number(value: float) -> float | None:
    """``value`` as a float, or ``None`` when it is NaN or infinite (JSON has neither)."""
    x = float(value)
    return x if math.isfinite(x) else None


def json_fields(record: Any) -> dict[str, Any]:
    """A dataclass's fields as a JSON-safe dict: NaN and infinite floats become ``None``."""
    from dataclasses import asdict

    return {k: json_number(v) if isinstance(v, float) else v for k, v in asdict(record).items()}


def write_bytes_atomic(target: str | Path, data: bytes) -> None:
    """Write ``data`` to ``target`` atomically."""
    with atomic_path(target) as tmp:
        tmp.write_bytes(data)


def savez_atomic(target: str | Path, /, **arrays: Any) -> None:
    """``np.savez`` to ``target`` atomically (numbers only: no pickled objects)."""
    import numpy as np

    with atomic_path(target) as tmp, tmp.open("wb") as f:
        np.savez(f, allow_pickle=False, **arrays)


def sha256_file(path: str | Path, chunk_bytes: int = 1 << 20) -> str:
    """SHA-256 of a file's bytes (hex), read in chunks so memory stays flat."""
    h = hashlib.sha256()
    with Path(path).open("rb") as f:
        while chunk := f.read(chunk_bytes):
            h.update(chunk)
    return h.hexdigest()
