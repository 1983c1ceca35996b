"""Results of sweep tasks, written once each, keyed by task configuration, data hash and code.

A rerun of an interrupted sweep finds finished tasks here and skips them. A task's result is
written atomically with a ``.sha256`` sidecar, and holds its configuration, the hashes of the
artifacts it names (result fields ending in ``_path``, stored relative to the store's base
folder so a moved study folder still works) and a hash of its own content. A result is used
only when all of these check out; otherwise it is reported, discarded and recomputed.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from drafttwin._io import sha256_file
from drafttwin.execution import integrity


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
    """Identity of a task: its public configuration, the hash of the data it reads and the
    code that computes it (:func:`code_fingerprint`)."""
    text = canonical_json(public(config)) + data_digest + code_fingerprint()
    return hashlib.sha256(text.encode()).hexdigest()


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """SHA-256 over the drafttwin package's Python sources (relative path and bytes of each):
    a result cached by other code is another result (a changed model or metric would
    otherwise be read back as if it were this one's). About 2 MB, read once per process."""
    package = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for path in sorted(package.rglob("*.py")):
        h.update(path.relative_to(package).as_posix().encode() + b"\0")
        h.update(path.read_bytes())
    return h.hexdigest()


class ResultStore:
    """A folder of ``<key>.json`` files, one per finished task.

    Args:
        root: the folder of result files.
        base: the folder that artifact paths are stored relative to (the study folder);
            default ``root``.
    """

    def __init__(self, root: str | Path, base: str | Path | None = None) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self.base = Path(base) if base is not None else self.root

    def _path(self, key: str) -> Path:
        return self.root / f"{key}.json"

    def fetch(self, key: str, config: dict[str, Any]) -> dict[str, Any] | None:
        """The stored result of the task ``key`` with ``config``, artifact paths resolved
        against :attr:`base`; ``None`` when there is none or it is damaged (then it is
        reported and discarded, and the caller recomputes it)."""
        path = self._path(key)
        doc = integrity.read_checked(path, lambda p: _load_doc(p, public(config)))
        if doc is None:
            return None
        damaged = 0
        for rel, digest in doc["artifacts"].items():
            artifact = self.base / rel
            reason = integrity.problem(artifact, expected=digest)
            if reason is not None:  # the result is only as good as the files it names
                integrity.discard(artifact, reason)
                damaged += 1
        if damaged:
            for p in (path, integrity.sidecar(path)):
                p.unlink(missing_ok=True)
            return None
        result: dict[str, Any] = doc["result"]
        for k, v in result.items():
            if k.endswith(PATH_SUFFIX) and isinstance(v, str):
                result[k] = str(self.base / v)
        return result

    def put(self, key: str, config: dict[str, Any], result: dict[str, Any]) -> None:
        """Store ``result`` (written once: a valid stored result is never overwritten)."""
        path = self._path(key)
        if path.is_file() and integrity.problem(path) is None:
            return
        stored, artifacts = dict(result), {}
        for k, v in result.items():
            if k.endswith(PATH_SUFFIX) and isinstance(v, str):
                stored[k] = self._relative(Path(v))
                artifacts[stored[k]] = integrity.recorded_hash(v) or sha256_file(v)
        body = {"format": FORMAT, "config": public(config), "result": stored,
                "artifacts": artifacts}  # fmt: skip
        doc = json.loads(json.dumps(body, default=json_default))  # as it will read back
        doc["sha256"] = _content_hash(doc)
        integrity.write_text_sealed(path, json.dumps(doc, sort_keys=True))

    def _relative(self, path: Path) -> str:
        rel = os.path.relpath(os.path.abspath(path), os.path.abspath(self.base))
        return Path(rel).as_posix() if not rel.startswith("..") else str(path.absolute())

    def __len__(self) -> int:
        # not the hidden temporary files of writes in progress (``.<name>.XXXX.json``)
        return sum(1 for p in self.root.glob("*.json") if not p.name.startswith("."))


FORMAT = "drafttwin-result-2"
"""Names the stored document's layout (config, result, artifacts, sha256)."""
PATH_SUFFIX = "_path"
"""Result fields whose value is an artifact file."""


def _content_hash(doc: dict[str, Any]) -> str:
    """Hash of a stored document's canonical content, without its own ``sha256`` field."""
    body = {k: v for k, v in doc.items() if k != "sha256"}
    return hashlib.sha256(canonical_json(body).encode()).hexdigest()


def _load_doc(path: Path, config: dict[str, Any]) -> dict[str, Any]:
    """A stored document, checked: layout, self-hash, and the configuration asked for."""
    doc = json.loads(path.read_text(encoding="utf-8"))
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ValueError("not a result document of this drafttwin version")
    if doc.get("sha256") != _content_hash(doc):
        raise ValueError("content does not match its self-hash")
    if canonical_json(doc["config"]) != canonical_json(config):
        raise ValueError("holds another task's configuration")
    if not isinstance(doc["result"], dict) or not isinstance(doc["artifacts"], dict):
        raise ValueError("result or artifact list is not a mapping")
    return doc
