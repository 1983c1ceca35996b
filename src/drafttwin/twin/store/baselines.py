"""Each machine's learned healthy state, kept in the store folder with the machine's identity.

``STORE/baselines/NAME.json`` holds the detector a machine learned
(:mod:`drafttwin.diagnosis.learning`), the identity it was learned on (its serial number,
when the source gives one), the model file it belongs to (SHA-256), how long it learned and
from when to when, and the prior it was combined with. A restarted twin reads it back and
watches at once; it refuses it (and the machine learns again) when the model changed, or when
the machine's source now says another serial number: a baseline of one machine never judges
another. Written atomically, checked field by field when read.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drafttwin.diagnosis.blocks import BlockRow
from drafttwin.diagnosis.detect import FaultDetector
from drafttwin.diagnosis.learning import Learner
from drafttwin.diagnosis.stream import RankRequest
from drafttwin.errors import DataError
from drafttwin.sliver.reference import SliverReference
from drafttwin.wire.identity import MachineIdentity

FORMAT = "drafttwin-machine-baseline"
VERSION = 1
_NAME = re.compile(r"^[A-Za-z0-9_.\-]{1,100}$")


@dataclass
class Baseline:
    """One machine's learned detector and where it came from."""

    machine: str
    detector: FaultDetector
    model_sha256: str
    identity: MachineIdentity | None
    learned_s: float
    from_s: float  # source time of the first and last learned block, s
    to_s: float
    prior: dict[str, Any] | None = None  # the prior's file name, SHA-256 and machines
    extra: dict[str, Any] = field(default_factory=dict)
    sliver_reference: SliverReference | None = None  # its sliver's own lines, when it had one

    def to_doc(self) -> dict[str, Any]:
        return {"format": FORMAT, "version": VERSION, "machine": self.machine,
                "identity": None if self.identity is None else self.identity.to_dict(),
                "model_sha256": self.model_sha256, "learned_s": self.learned_s,
                "from_s": self.from_s, "to_s": self.to_s, "prior": self.prior,
                "detector": self.detector.to_state(), "describe": self.detector.describe(),
                "sliver_reference": None if self.sliver_reference is None
                else self.sliver_reference.to_doc()}  # fmt: skip

    def summary(self) -> dict[str, Any]:
        """What the page and /api/status show of it."""
        return {"identity": None if self.identity is None else self.identity.to_dict(),
                "learned_s": self.learned_s, "from_s": self.from_s, "to_s": self.to_s,
                "prior": None if self.prior is None else self.prior.get("file"),
                "lags_watched": self.detector.lags_watched}  # fmt: skip


class BaselineStore:
    """The ``baselines`` folder of a twin's store."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)

    def path(self, machine: str) -> Path:
        if not _NAME.match(machine):
            raise DataError(f"machine name {machine!r} cannot name a file", where="machine",
                            fix="name machines with letters, digits, '.', '_' and '-'")  # fmt: skip
        return self.folder / f"{machine}.json"

    def save(self, b: Baseline) -> Path:
        from drafttwin._io import atomic_path
        from drafttwin._json import dumps_strict

        self.folder.mkdir(parents=True, exist_ok=True)
        target = self.path(b.machine)
        with atomic_path(target) as tmp:
            tmp.write_text(dumps_strict(b.to_doc()), encoding="utf-8")
        return target

    def set_aside(self, machine: str) -> Path:
        """A damaged baseline moved out of the way (``NAME.json.damaged``), for a look."""
        path = self.path(machine)
        target = path.with_name(path.name + ".damaged")
        path.replace(target)
        return target

    def forget(self, machine: str) -> None:
        """An operator's relearn: the stored baseline goes (a new one is written when the
        machine has learned again)."""
        self.path(machine).unlink(missing_ok=True)

    def load(self, machine: str) -> Baseline | None:
        """The machine's baseline, or ``None`` when there is none; a damaged file is refused
        with a :class:`~drafttwin.errors.DataError` naming it."""
        path = self.path(machine)
        if not path.is_file():
            return None
        fix = f"delete {path} (the machine then learns again)"
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise DataError(f"cannot read the baseline ({type(exc).__name__})", source=path,
                            fix=fix) from None  # fmt: skip
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise DataError("not a drafttwin machine baseline", source=path, fix=fix)
        if doc.get("version") != VERSION or doc.get("machine") != machine:
            raise DataError(f"baseline version {doc.get('version')!r} of machine "
                            f"{doc.get('machine')!r}, expected version {VERSION} of {machine!r}",
                            source=path, fix=fix)  # fmt: skip
        ident = doc.get("identity")
        identity = None if ident is None else MachineIdentity.from_dict(ident)
        if ident is not None and identity is None:
            raise DataError("the baseline's identity is malformed", source=path,
                            where="identity", fix=fix)  # fmt: skip
        nums: list[float] = []
        for k in ("learned_s", "from_s", "to_s"):
            v = doc.get(k)
            if not (isinstance(v, int | float) and math.isfinite(v)):
                raise DataError(f"{k} is not a number", source=path, where=k, fix=fix)
            nums.append(float(v))
        sha, prior = doc.get("model_sha256"), doc.get("prior")
        if not (isinstance(sha, str) and re.fullmatch(r"[0-9a-f]{64}", sha)):
            raise DataError("model_sha256 is not a SHA-256", source=path, fix=fix)
        if prior is not None and not isinstance(prior, dict):
            raise DataError("prior is not an object", source=path, fix=fix)
        if not isinstance(doc.get("detector"), dict):
            raise DataError("the baseline holds no detector", source=path, fix=fix)
        detector = FaultDetector.from_state(doc["detector"], source=str(path))
        lines = doc.get("sliver_reference")  # absent in baselines stored before it was kept
        sliver = None if lines is None else SliverReference.from_doc(lines, str(path), fix)
        return Baseline(machine, detector, sha, identity, nums[0], nums[1], nums[2], prior,
                        sliver_reference=sliver)  # fmt: skip

    # ---- what a stopped twin leaves to the next one ---------------------------------------
    def save_learning(self, machine: str, learner: Learner, identity: MachineIdentity | None,
                      model_sha256: str, from_s: float | None) -> None:  # fmt: skip
        """A learning state's blocks so far (``NAME.learning.json``): a restarted twin goes on
        learning the same machine instead of starting over."""
        from drafttwin._io import atomic_path
        from drafttwin._json import dumps_strict

        records = [[_row(r) for r in rec] for rec in learner.records if rec]
        doc = {"format": FORMAT + "-learning", "version": VERSION, "machine": machine,
               "identity": None if identity is None else identity.to_dict(),
               "model_sha256": model_sha256, "learn_s": learner.learn_s,
               "block_s": learner.block_s, "from_s": from_s, "records": records}  # fmt: skip
        self.folder.mkdir(parents=True, exist_ok=True)
        with atomic_path(self.folder / f"{machine}.learning.json") as tmp:
            tmp.write_text(dumps_strict(doc), encoding="utf-8")

    def load_learning(self, machine: str, identity: MachineIdentity | None, model_sha256: str,
                      learner: Learner) -> float | None:  # fmt: skip
        """Put a kept learning state's blocks into ``learner`` when it was this machine's (and
        model's); the source time it began (None: nothing kept, or not this machine's). A
        damaged file is set aside."""
        path = self.folder / f"{machine}.learning.json"
        if not path.is_file():
            return None
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
            if doc.get("format") != FORMAT + "-learning" or doc.get("machine") != machine:
                raise ValueError("not this machine's learning state")
            kept = doc.get("identity")
            if doc.get("model_sha256") != model_sha256 or (
                kept is not None and identity is not None and kept != identity.to_dict()
            ):
                return None
            records = [[_unrow(r) for r in rec] for rec in doc["records"]]
            block_s = float(doc["block_s"]) if doc.get("block_s") is not None else None
            from_s = doc.get("from_s")
        except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError):
            path.replace(path.with_name(path.name + ".damaged"))
            return None
        learner.records = [*records, []] if records else [[]]
        learner.block_s = block_s
        return float(from_s) if isinstance(from_s, int | float) else None

    def forget_learning(self, machine: str) -> None:
        (self.folder / f"{machine}.learning.json").unlink(missing_ok=True)

    def save_pending(self, machine: str, req: RankRequest, detector: FaultDetector,
                     post_s: float) -> Path:  # fmt: skip
        """A window whose ranking a stop cut short, kept to be ranked when the twin starts
        again (``pending/NAME-ALARM_US.json``)."""
        from drafttwin._io import atomic_path
        from drafttwin._json import dumps_strict

        folder = self.folder / "pending"
        folder.mkdir(parents=True, exist_ok=True)
        target = folder / f"{machine}-{int(round(req.alarm.time_s * 1e6))}.json"
        doc = {"format": FORMAT + "-pending", "version": VERSION, "machine": machine,
               "post_s": post_s, "detector": detector.to_state(), "request": req.to_doc()}  # fmt: skip
        with atomic_path(target) as tmp:
            tmp.write_text(dumps_strict(doc), encoding="utf-8")
        return target

    def pending(self, machine: str) -> list[tuple[Path, RankRequest, FaultDetector, float]]:
        """The machine's kept windows (checked; a damaged one is set aside)."""
        out = []
        for path in sorted((self.folder / "pending").glob(f"{machine}-*.json")):
            try:
                doc = json.loads(path.read_text(encoding="utf-8"))
                if doc.get("format") != FORMAT + "-pending" or doc.get("machine") != machine:
                    raise ValueError("not this machine's window")
                post = float(doc["post_s"])
                if not (math.isfinite(post) and post > 0):
                    raise ValueError("post_s")
                req = RankRequest.from_doc(doc["request"])
                det = FaultDetector.from_state(doc["detector"], source=str(path))
            except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, DataError):
                path.replace(path.with_name(path.name + ".damaged"))
                continue
            out.append((path, req, det, post))
        return out


def _row(r: BlockRow) -> list[float]:
    return [float(r.index), r.time_s, *r.level.tolist(), *r.lost.tolist(), *r.run.tolist(),
            *r.lag.tolist(), *r.stale.tolist()]  # fmt: skip


def _unrow(v: Any) -> BlockRow:
    a = np.asarray(v, dtype=np.float64)
    # 20 numbers: a block learned before 2026-11-29, without its stale runs
    if a.shape not in ((20,), (25,)) or not np.isfinite(a).all():
        raise ValueError("a learned block is not 25 (or 20) finite numbers")
    return BlockRow(int(a[0]), float(a[1]), a[2:7], a[7:12], a[12:17], a[17:20],
                    a[20:25] if len(a) == 25 else None)  # fmt: skip


__all__ = ["Baseline", "BaselineStore"]
