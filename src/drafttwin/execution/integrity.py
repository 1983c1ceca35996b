"""Cache files that are checked before they are used.

Every file the study caches gets a ``<name>.sha256`` sidecar (``sha256sum`` format, so
``sha256sum -c`` works in the folder), written after the file itself. Reading a cache file back
goes through :func:`read_checked`: the file's hash must match its sidecar and the loader (which
validates the content) must succeed. A damaged, truncated, altered or sidecar-less entry is
never used: it is renamed to ``<name>.damaged`` (kept for inspection), one line on stderr names
it, and the caller recomputes it.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from drafttwin._io import atomic_path, sha256_file, write_text_atomic

if TYPE_CHECKING:
    import numpy as np

T = TypeVar("T")

SIDECAR_SUFFIX = ".sha256"
DAMAGED_SUFFIX = ".damaged"
_HEX_DIGITS = 64


def sidecar(path: str | Path) -> Path:
    """The file that holds ``path``'s SHA-256."""
    path = Path(path)
    return path.with_name(path.name + SIDECAR_SUFFIX)


@contextlib.contextmanager
def sealed_path(target: str | Path) -> Iterator[Path]:
    """Like :func:`drafttwin._io.atomic_path`, and the sidecar is written once the temporary
    file is complete, just before the rename: a run killed in between leaves at most a
    sidecar without its file, which reads as a missing entry, not a damaged one."""
    target = Path(target)
    with atomic_path(target) as tmp:
        yield tmp
        write_text_atomic(sidecar(target), f"{sha256_file(tmp)}  {target.name}\n")


def write_text_sealed(target: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) atomically, with its sidecar."""
    with sealed_path(target) as tmp:
        tmp.write_text(text, encoding="utf-8")


def save_npy_sealed(target: str | Path, array: np.ndarray) -> None:
    """``np.save`` atomically (numbers only), with its sidecar."""
    import numpy as np

    with sealed_path(target) as tmp, tmp.open("wb") as f:
        np.save(f, np.asarray(array), allow_pickle=False)


def savez_sealed(target: str | Path, /, **arrays: Any) -> None:
    """``np.savez`` atomically (numbers only), with its sidecar."""
    import numpy as np

    with sealed_path(target) as tmp, tmp.open("wb") as f:
        np.savez(f, allow_pickle=False, **arrays)


def load_array(path: Path, shape: tuple[int, ...] | None = None) -> np.ndarray:
    """A float array from an ``.npy`` file (no pickles), of ``shape`` when given: a loader for
    :func:`read_checked`."""
    import numpy as np

    array: np.ndarray = np.load(path, allow_pickle=False)
    if array.dtype.kind != "f":
        raise ValueError(f"holds {array.dtype}, not floats")
    if shape is not None and array.shape != shape:
        raise ValueError(f"holds shape {array.shape}, expected {shape}")
    return array


def recorded_hash(path: str | Path) -> str | None:
    """The hash in ``path``'s sidecar, or ``None`` when the sidecar is missing or malformed."""
    try:
        text = sidecar(path).read_text(encoding="ascii")
    except (OSError, UnicodeDecodeError):
        return None
    fields = text.split()
    if len(fields) != 2 or fields[1] != Path(path).name or len(fields[0]) != _HEX_DIGITS:
        return None
    digest = fields[0].lower()
    return digest if all(c in "0123456789abcdef" for c in digest) else None


def problem(path: str | Path, expected: str | None = None) -> str | None:
    """Why ``path`` cannot be trusted (a short reason), or ``None`` when it checks out.

    ``expected``: a hash recorded elsewhere (a result's artifact list) that must match too."""
    path = Path(path)
    if not path.is_file():
        return "missing"
    recorded = recorded_hash(path)
    if recorded is None:
        return "its .sha256 sidecar is missing or malformed"
    try:
        actual = sha256_file(path)
    except OSError as exc:
        return f"unreadable ({exc.strerror or type(exc).__name__})"
    if actual != recorded or (expected is not None and actual != expected):
        return "sha256 mismatch"
    return None


def discard(path: str | Path, reason: str) -> None:
    """Move a bad entry aside as ``<name>.damaged`` (with its sidecar) and say so, in one line,
    on stderr. The next run recomputes it."""
    path = Path(path)
    for p in (path, sidecar(path)):
        # in a read-only cache the rename fails: the entry is still not used
        with contextlib.suppress(OSError):
            if p.exists():
                os.replace(p, p.with_name(p.name + DAMAGED_SUFFIX))
    print(f"cache entry {path} is damaged ({reason}); discarded, recomputing", file=sys.stderr)


def read_checked(path: str | Path, loader: Callable[[Path], T]) -> T | None:
    """``loader(path)`` when ``path`` matches its sidecar and loads; ``None`` when it is absent
    or damaged (then it is discarded, see :func:`discard`). ``loader`` validates the content
    and raises on anything wrong; whatever it raises counts as damage, never a traceback."""
    path = Path(path)
    if not path.exists():
        return None
    reason = problem(path)
    if reason is None:
        try:
            return loader(path)
        except Exception as exc:  # noqa: BLE001  (any failure to load is damage)
            detail = " ".join(str(exc).split())[:120]  # one line
            reason = f"unreadable: {type(exc).__name__}: {detail}"
    discard(path, reason)
    return None
