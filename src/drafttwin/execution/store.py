"""Results of sweep tasks, written once each, keyed by task configuration and data hash.

A rerun of an interrupted sweep finds finished tasks here and skips them; a task's result is
written atomically, so an interruption never leaves a half-written result behind.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np

from drafttwin._io import write_text_atomic


def canonical_json(obj: Any) -> str:
    """JSON with sorted keys and no whitespace: equal configurations give equal text."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=json_default)


def json_default(obj: Any) -> Any:
    """``json.dumps(default=...)`` for NumPy scalars and arrays and paths."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON-serialisable: {type(obj).__name__}")


def data_hash(*arrays: np.ndarray) -> str:
    """SHA-256 over the arrays' shapes, dtypes and bytes (NaN-aware, order-sensitive)."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.shape}{a.dtype.str}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def public(config: dict[str, Any]) -> dict[str, Any]:
    """The configuration without context entries (keys starting with ``_``, e.g. file paths)."""
    return {k: v for k, v in config.items() if not k.startswith("_")}


def task_key(config: dict[str, Any], data_digest: str) -> str:
    """Identity of a task: its public configuration and the hash of the data it reads."""
    return hashlib.sha256((canonical_json(public(config)) + data_digest).encode()).hexdigest()


class ResultStore:
    """A folder of ``<key>.json`` files, one per finished task."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)

    def _path(self, key: str) -> Path:
        return self.root / f"{key}.json"

    def has(self, key: str) -> bool:
        return self._path(key).is_file()

    def get(self, key: str) -> dict[str, Any]:
        return json.loads(self._path(key).read_text(encoding="utf-8"))["result"]

    def put(self, key: str, config: dict[str, Any], result: dict[str, Any]) -> None:
        if self.has(key):  # written once: a finished task is never overwritten
            return
        doc = {"config": public(config), "result": result}
        write_text_atomic(self._path(key), json.dumps(doc, default=json_default, sort_keys=True))

    def __len__(self) -> int:
        return sum(1 for _ in self.root.glob("*.json"))
