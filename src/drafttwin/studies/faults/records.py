"""The fault benchmark's plant records, kept on disk and checked when read back.

A plant record costs about 5.6 CPU-s per minute of machine time (the full drive train); the
24-h benchmark's 26 h of records cost 2.3 CPU-hours. With a records folder each task's record
is made once: ``FOLDER/NAME-KEY.parquet`` (the measured rollers, motor and set-point, as
``drafttwin generate`` writes them, floats bit-identical when read back) beside
``FOLDER/NAME-KEY.json`` (the fault labels, the machine seed, the task's configuration), each
sealed with a ``.sha256`` sidecar (:mod:`drafttwin.execution.integrity`): a damaged file is
set aside and the record made again. ``KEY`` is the hash of the task's configuration and of
the plant's own code, so records of another plant are never read as this one's; the
diagnosis may change freely and re-score the same records in minutes. The live benchmark
(:mod:`.live`) serves these very files over the wire.
"""

from __future__ import annotations

import functools
import hashlib
import json
from pathlib import Path
from typing import Any

from drafttwin.data.io import read_measurements, write_measurements
from drafttwin.data.series import MeasurementSeries
from drafttwin.execution.integrity import read_checked, sealed_path, write_text_sealed
from drafttwin.execution.store import canonical_json, public

PLANT_CODE = ("plant", "mechanics")
"""Packages whose code makes a record (their sources are hashed into its key); the plant's
servers and live stepper are not part of a recording."""
_NOT_RECORDING = ("plant/serve/", "plant/live.py")


@functools.lru_cache(maxsize=1)
def plant_code_fingerprint() -> str:
    """SHA-256 over the sources that make a plant record (path and bytes of each)."""
    package = Path(__file__).resolve().parents[2]
    h = hashlib.sha256()
    for sub in PLANT_CODE:
        for path in sorted((package / sub).rglob("*.py")):
            rel = path.relative_to(package).as_posix()
            if rel.startswith(_NOT_RECORDING):
                continue
            h.update(rel.encode() + b"\0" + path.read_bytes())
    return h.hexdigest()


def record_key(config: dict[str, Any]) -> str:
    """The record's identity: its configuration and the plant's code."""
    text = canonical_json(public(config)) + plant_code_fingerprint()
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def record_path(folder: Path, config: dict[str, Any]) -> Path:
    """Where a task's record lives in ``folder``."""
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in str(config["name"]))
    return Path(folder) / f"{safe}-{record_key(config)}.parquet"


def load_record(path: Path) -> tuple[MeasurementSeries, list[dict[str, Any]]] | None:
    """A kept record (its series and fault labels), ``None`` when absent or damaged (then
    set aside, and made again by the caller)."""
    meta = read_checked(path.with_suffix(".json"), _read_meta)
    if meta is None:
        return None
    series = read_checked(path, lambda p: read_measurements(p, check_units=False))
    if series is None or series.motor_rpm is None:
        return None
    return series, meta["labels"]


def _read_meta(path: Path) -> dict[str, Any]:
    doc = json.loads(path.read_text(encoding="utf-8"))
    if not isinstance(doc, dict) or not isinstance(doc.get("labels"), list):
        raise ValueError("no labels")
    return doc


def save_record(path: Path, config: dict[str, Any], series: MeasurementSeries,
                labels: list[dict[str, Any]]) -> None:  # fmt: skip
    """Keep a record: the series, then its labels (each sealed; the labels last, so a run
    killed in between leaves a record without labels, which reads as absent)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with sealed_path(path) as tmp:
        write_measurements(series, tmp.with_suffix(".parquet"))
        tmp.with_suffix(".parquet").replace(tmp)
    doc = {"config": public(config), "labels": labels, "key": record_key(config)}
    write_text_sealed(path.with_suffix(".json"), canonical_json(doc))


__all__ = ["load_record", "plant_code_fingerprint", "record_key", "record_path", "save_record"]
