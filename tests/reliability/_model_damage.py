"""A catalogue of damaged model files: every field of a saved file times the ways it breaks.

Used by ``test_model_files.py`` and, to count cases handled cleanly before and after a
change, by running :func:`count` against any drafttwin checkout (only the public API and
``torch`` are used). Each case edits the payload of a freshly saved tiny GRU model (or its
bytes) and says what a clean outcome is: ``refuse`` (a ModelFileError naming the file) or
``cpu`` (loads with a warning and predicts on the CPU).
"""

from __future__ import annotations

import contextlib
import json
import math
import pickle
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

Payload = dict[str, Any]

NAN = math.nan


@dataclass(frozen=True)
class Case:
    """One damaged file: ``edit`` changes the payload, ``raw`` the bytes (either or both)."""

    name: str
    edit: Callable[[Payload], None] | None = None
    raw: Callable[[bytes], bytes] | None = None
    expect: str = "refuse"  # or "cpu"
    reseal: bool = True  # recompute the checksum after the edit, as a forger would

    def write(self, good: Path, target: Path) -> Path:
        if self.edit is not None:
            payload = torch.load(good, weights_only=True)
            self.edit(payload)
            if self.reseal and isinstance(payload.get("checksum"), str):
                _reseal(payload)
            torch.save(payload, target)
        else:
            target.write_bytes(good.read_bytes())
        if self.raw is not None:
            target.write_bytes(self.raw(target.read_bytes()))
        return target


def _reseal(payload: Payload) -> None:
    """A valid checksum for the edited payload, so that the check of the field itself runs
    (a crafted file carries a matching checksum; a stale one is a case of its own)."""
    from drafttwin.models.storage.modelfile import checksum

    with contextlib.suppress(Exception):  # a payload too broken to hash: load refuses it
        payload["checksum"] = checksum(payload)


# ----- editing helpers ------------------------------------------------------------------------
def _json_edit(key: str, path: tuple[str, ...], value: Any, *, delete: bool = False):
    def edit(payload: Payload) -> None:
        data = json.loads(payload[key])
        node = data
        for part in path[:-1]:
            node = node[part]
        if delete:
            del node[path[-1]]
        else:
            node[path[-1]] = value
        payload[key] = json.dumps(data)

    return edit


def _param(*path: str, value: Any = None, delete: bool = False):
    return _json_edit("params_json", path, value, delete=delete)


def _state(*path: str, value: Any = None, delete: bool = False):
    return _json_edit("state_json", path, value, delete=delete)


def _top(key: str, value: Any = None, *, delete: bool = False):
    def edit(payload: Payload) -> None:
        if delete:
            del payload[key]
        else:
            payload[key] = value

    return edit


def _tensor(name_part: str, change: Callable[[torch.Tensor], torch.Tensor | None]):
    def edit(payload: Payload) -> None:
        tensors = payload["tensors"]
        name = next(k for k in tensors if name_part in k)
        new = change(tensors[name])
        if new is None:
            del tensors[name]
        else:
            tensors[name] = new

    return edit


def _with_nan(t: torch.Tensor) -> torch.Tensor:
    t = t.clone()
    t.view(-1)[0] = math.nan
    return t


def _extra_tensor(payload: Payload) -> None:
    payload["tensors"]["net.extra"] = torch.zeros(3)


def _flip_weight_bit(good: bytes) -> bytes:
    """Flip one bit of the largest tensor's stored bytes (a disk or transfer error)."""
    import io
    import struct
    import zipfile

    storages = [i for i in zipfile.ZipFile(io.BytesIO(good)).infolist() if "/data/" in i.filename]
    info = max(storages, key=lambda i: i.file_size)
    name_len, extra_len = struct.unpack(
        "<HH", good[info.header_offset + 26 : info.header_offset + 30]
    )
    at = info.header_offset + 30 + name_len + extra_len + info.file_size // 2
    return good[:at] + bytes([good[at] ^ 0x10]) + good[at + 1 :]


class _RunsCode:
    """A pickle that would create ``marker`` when unpickled (it must never be)."""

    marker = Path("/tmp/drafttwin_model_damage_pwned")

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def _evil_pickle(_: bytes) -> bytes:
    return pickle.dumps({"format": "drafttwin-model", "payload": _RunsCode()}, protocol=2)


def _evil_torch(good: bytes) -> bytes:  # the same object inside torch's zip format
    import io

    buf = io.BytesIO()
    torch.save({"format": "drafttwin-model", "payload": _RunsCode()}, buf)
    return buf.getvalue()


# ----- the catalogue ------------------------------------------------------------------------
def cases() -> list[Case]:
    """Every field of a GRU model file times each damage that applies to it."""
    out: list[Case] = []

    def add(name: str, edit=None, raw=None, expect: str = "refuse", reseal: bool = True) -> None:
        out.append(Case(name, edit, raw, expect, reseal))

    # the file as a whole
    add("file: truncated to half", raw=lambda b: b[: len(b) // 2])
    add("file: truncated by one byte", raw=lambda b: b[:-1])
    add("file: empty", raw=lambda b: b"")
    add("file: random bytes (not a zip or pickle)", raw=lambda b: bytes(range(256)) * 40)
    add("file: a CSV text", raw=lambda b: b"time,front\n0,1815\n")
    add("file: a plain pickle that would run code", raw=_evil_pickle)
    add("file: a torch file whose pickle would run code", raw=_evil_torch)
    add("file: a bit flipped inside a weight's bytes", raw=_flip_weight_bit)
    # payload fields
    for key in ("format", "format_version", "drafttwin_version", "model_class", "model_name",
                "params_json", "state_json", "tensors"):  # fmt: skip
        add(f"payload.{key}: missing", _top(key, delete=True))
        add(f"payload.{key}: wrong type", _top(key, 12345 if key != "format_version" else "2"))
    add("payload: unknown extra key", _top("extra", "x"))
    add("payload.checksum: stale after an edit", _param("seed", value=7), reseal=False)
    add("payload.format_version: future", _top("format_version", 99))
    add("payload.model_class: unknown kind", _top("model_class", "EvilModel"))
    add("payload.model_class: another class", _top("model_class", "LSTMModel"))
    add("payload.params_json: not JSON", _top("params_json", "{not json"))
    add("payload.params_json: a JSON list", _top("params_json", "[1, 2]"))
    add("payload.state_json: not JSON", _top("state_json", "{not json"))
    add("payload.state_json: a JSON list", _top("state_json", "[]"))
    # hyperparameters
    for field, bad in [("window", 0), ("window", -3), ("window", "8"), ("window", 8.5),
                       ("window", 10**12), ("window", True), ("hidden", 0), ("hidden", 10**7),
                       ("hidden", 5), ("layers", 0), ("layers", 3), ("dropout", 1.5),
                       ("dropout", NAN), ("dropout", "x"), ("skip", "yes"), ("seed", -1),
                       ("seed", 1.5), ("quiet", "no")]:  # fmt: skip
        add(f"params.{field}: {bad!r}", _param(field, value=bad))
    for field in ("window", "hidden", "task", "training"):
        add(f"params.{field}: missing", _param(field, delete=True))
    add("params: unknown extra key", _param("evil", value=1))
    add("params.task: unknown class tag", _param("task", value={"__model__": "Evil", "params": {}}))
    for field, bad in [("kind", "bogus"), ("horizon", 0), ("horizon", "1"), ("outputs", 5),
                       ("outputs", ["front"]), ("inputs", ["front"]), ("init_samples", 5)]:  # fmt: skip
        add(f"params.task.{field}: {bad!r}", _param("task", "__task__", field, value=bad))
    add("params.task.horizon: missing", _param("task", "__task__", "horizon", delete=True))
    add("params.task: unknown extra key", _param("task", "__task__", "evil", value=1))
    for field, bad in [("epochs", 0), ("lr", NAN), ("lr", -1.0), ("batch_size", "64"),
                       ("val_fraction", 1.0), ("device", "tpu"), ("device", 5),
                       ("device", "meta")]:  # fmt: skip
        add(f"params.training.{field}: {bad!r}", _param("training", "__training__", field,
                                                        value=bad))  # fmt: skip
    add("params.training: unknown extra key", _param("training", "__training__", "evil", value=1))
    add("params.training.lr: missing", _param("training", "__training__", "lr", delete=True))
    for device in ("cuda", "cuda:3", "mps"):
        add(f"params.training.device: {device} (absent here)",
            _param("training", "__training__", "device", value=device), expect="cpu")  # fmt: skip
    # fitted state
    for field in ("channels", "units", "mechanistic", "sample_rate_hz", "selection",
                  "provenance", "history", "scaler"):  # fmt: skip
        add(f"state.{field}: missing", _state(field, delete=True))
    add("state: unknown extra key", _state("evil", value=1))
    for field, bad in [("channels", "front"), ("channels", ["a", "a", "b", "c"]),
                       ("channels", ["a", "b"]), ("channels", []), ("units", ["rpm"]),
                       ("units", {"front": 5}), ("sample_rate_hz", NAN),
                       ("sample_rate_hz", -100.0), ("sample_rate_hz", "100"),
                       ("selection", [1]), ("provenance", "x"),
                       ("mechanistic", {"kind": "exec", "code": "x"}),
                       ("mechanistic", {"kind": "preset", "name": "../../etc/passwd"}),
                       ("mechanistic", {"kind": "train", "name": "t", "spec": {"evil": 1}}),
                       ("mechanistic", {"kind": "file", "paths": 5}),
                       ("mechanistic", {"kind": "preset", "name": "fa320a", "cutoff_hz": -200}),
                       ("mechanistic", {"kind": "preset", "name": "fa320a", "cutoff_hz": NAN}),
                       ("mechanistic", {"kind": "preset", "name": "fa320a", "cutoff_hz": "200"}),
                       ("mechanistic", {"kind": "file", "paths": ["a.csv"], "cutoff_hz": 200}),
                       ("mechanistic", "preset"), ("history", [1]),
                       ("history", {"train_loss": []})]:  # fmt: skip
        add(f"state.{field}: {bad!r}", _state(field, value=bad))
    for field, bad in [("min", [NAN, 0, 0, 0]), ("max", [math.inf, 1, 1, 1]),
                       ("min", [0.0]), ("min", "x"), ("max", [-1e9, -1e9, -1e9, -1e9])]:  # fmt: skip
        add(f"state.scaler.{field}: {bad!r}", _state("scaler", field, value=bad))
    add("state.scaler: unknown extra key", _state("scaler", "evil", value=1))
    add("state.history.best_epoch: 'x'", _state("history", "best_epoch", value="x"))
    # tensors
    add("tensors: NaN in a weight", _tensor("weight", _with_nan))
    add("tensors: inf in a bias", _tensor("bias", lambda t: t + math.inf))
    add("tensors: wrong shape", _tensor("weight", lambda t: torch.zeros(3, 3)))
    add("tensors: missing", _tensor("weight", lambda t: None))
    add("tensors: integer dtype", _tensor("weight", lambda t: t.to(torch.int64)))
    add("tensors: unknown extra tensor", _extra_tensor)
    return out


def check(case: Case, good: Path, target: Path, series: Any) -> tuple[bool, str]:
    """``(clean, what happened)`` for one case against the installed drafttwin."""
    import warnings

    from drafttwin.errors import DrafttwinError
    from drafttwin.models import load_model

    _RunsCode.marker.unlink(missing_ok=True)
    path = case.write(good, target)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            model = load_model(path)
            pred = model.predict_values(series)
    except DrafttwinError as exc:
        ran = _RunsCode.marker.exists()
        one = str(path) in str(exc) and not ran
        return case.expect == "refuse" and one, f"{type(exc).__name__}: {str(exc)[:150]}"
    except Exception as exc:  # noqa: BLE001  (counting what escapes)
        return False, f"TRACEBACK {type(exc).__name__}: {str(exc)[:150]}"
    warned = any("cpu" in str(w.message) for w in caught)
    if case.expect == "cpu":
        return warned and pred.shape[0] == len(series), f"loaded, warned={warned}"
    return False, "accepted silently"


def count(workdir: Path) -> dict[str, Any]:
    """Fit the tiny GRU, write every case, and count the clean outcomes."""
    from drafttwin.models import make_model
    from tests._synthetic import hyper_for, make_series

    series = make_series(300, seed=2)[0]
    good = workdir / "good.pt"
    make_model("gru", **hyper_for("gru")).fit(series).save(good)
    results = []
    for k, case in enumerate(cases()):
        ok, what = check(case, good, workdir / f"case{k}.pt", series)
        results.append({"case": case.name, "clean": ok, "outcome": what})
    return {"cases": len(results), "clean": sum(r["clean"] for r in results), "results": results}


if __name__ == "__main__":
    import sys
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        summary = count(Path(tmp))
    for r in summary["results"]:
        if not r["clean"] or "-v" in sys.argv:
            print(("ok  " if r["clean"] else "BAD ") + r["case"], "->", r["outcome"])
    print(f"{summary['clean']}/{summary['cases']} handled cleanly")
