"""Fault detection and probable cause in the live path: the offline diagnosis, fed row by row.

Per machine, :class:`LiveFaultWatch` pushes each processed row (in time order: measured and
open-loop physics speeds of the four rollers and the motor) into the diagnosis's own
:class:`~drafttwin.diagnosis.stream.DiagnosisStream`: the same blocks, lags, statistics,
thresholds and windows as ``drafttwin diagnose`` on the same rows (tested by replay), so the
live word is the offline one. A machine new to the twin first learns its healthy state
(:mod:`drafttwin.diagnosis.learning`; no fault alarm meanwhile), on top of the model's
detector file as a prior when there is one; its baseline is kept in the store with its
identity (:mod:`drafttwin.twin.store.baselines`).

A window's ranking (SciPy fits, about a second) runs in a separate process
(:class:`Locator`), so it never holds up any machine's samples; a sensor rule names its
channel at once, its window sizes the fault on the samples.

The detector file (``MODEL.dtm.detector.json``, :func:`save_detector`) is tied to the model
file by its SHA-256 and names the records (and machines) it was fitted on.
"""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from drafttwin._constants import ROLLERS
from drafttwin._io import sha256_file
from drafttwin.diagnosis.clearance import carries_over
from drafttwin.diagnosis.cusum import FEATURES, Alarm
from drafttwin.diagnosis.detect import FaultDetector
from drafttwin.diagnosis.diagnose import Diagnoser, sensor_cause
from drafttwin.diagnosis.learning import Learner, learn_time
from drafttwin.diagnosis.locate import SignatureModel
from drafttwin.diagnosis.residuals import CHANNELS
from drafttwin.diagnosis.stream import BLOCK_S, POST_S, DiagnosisStream, RankRequest, Step
from drafttwin.errors import ConfigError, DataError
from drafttwin.mechanics import DriveTrain
from drafttwin.twin.store.db import SampleRow
from drafttwin.wire.plantlog import plant_log_series as plant_log_series  # fit-detector's

FORMAT = "drafttwin-live-detector"
VERSION = 1
TOP = 3
"""Causes kept per alarm (the best first)."""
MAX_PENDING = 32
"""Localisations queued at once; more alarms in that time get no cause ('busy')."""


def detector_path(model: Path) -> Path:
    """Where a model's detector lives: next to it, ``MODEL.dtm.detector.json``."""
    return model.with_name(model.name + ".detector.json")


def save_detector(path: Path, detector: FaultDetector, model: Path, fitted_on: list[str],
                  post_s: float = POST_S, machines: list[str] | None = None) -> None:  # fmt: skip
    """Write the fitted detector (atomic), tied to ``model`` by its SHA-256, with the live
    post-alarm window ``post_s`` and the serial numbers of the ``machines`` its records were
    made on (where their files say)."""
    from drafttwin._io import atomic_path
    from drafttwin._json import dumps_strict

    doc = {"format": FORMAT, "version": VERSION, "model_file": model.name,
           "model_sha256": sha256_file(model), "fitted_on": fitted_on,
           "machines": sorted(set(machines or [])), "post_s": post_s,
           "detector": detector.to_state(), "describe": detector.describe()}  # fmt: skip
    with atomic_path(path) as tmp:
        tmp.write_text(dumps_strict(doc), encoding="utf-8")


def load_detector(path: Path, model: Path) -> tuple[FaultDetector, float, dict[str, Any]]:
    """Read a detector, its post-alarm window (s) and where it came from (the file, its
    SHA-256, the records and machines it was fitted on) back, refusing one of another format
    or fitted for another model."""
    fix = f"fit it again: drafttwin twin fit-detector --model {model} --healthy FILES"
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataError(f"cannot read the detector ({type(exc).__name__})", source=path,
                        fix=fix) from None  # fmt: skip
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise DataError("not a drafttwin live detector file", source=path, fix=fix)
    if doc.get("version") != VERSION:
        raise DataError(f"detector format version {doc.get('version')}, this drafttwin reads "
                        f"{VERSION}", source=path, fix=fix)  # fmt: skip
    if doc.get("model_sha256") != sha256_file(model):
        raise DataError(f"the detector was fitted for another model file "
                        f"({doc.get('model_file')!r}, a different SHA-256)", source=path,
                        where="model_sha256", fix=fix)  # fmt: skip
    state, post = doc.get("detector"), doc.get("post_s")
    if not isinstance(state, dict):
        raise DataError("the detector file has no fitted detector", source=path, fix=fix)
    if not (isinstance(post, int | float) and math.isfinite(post) and 0 < post <= 3600):
        raise DataError(f"post_s = {post!r} is not a number of seconds in (0, 3600]",
                        source=path, where="post_s", fix=fix)  # fmt: skip
    machines = doc.get("machines", [])
    if not (isinstance(machines, list) and all(isinstance(m, str) for m in machines)):
        raise DataError("machines is not a list of serial numbers", source=path,
                        where="machines", fix=fix)  # fmt: skip
    origin = {"file": path.name, "sha256": sha256_file(path), "machines": machines,
              "fitted_on": [str(f) for f in doc.get("fitted_on", [])][:100]}  # fmt: skip
    return FaultDetector.from_state(state, source=str(path)), float(post), origin


class LiveFaultWatch:
    """The diagnosis of one machine, fed row by row (see the module docstring).

    Args:
        machine: the machine's name.
        channels: the model's output channels (must be the four rollers).
        rate_hz: the machine's sample rate.
        ratio: the rollers' kinematic speed ratios
            (:func:`~drafttwin.diagnosis.residuals.roller_ratio` of the twin's train).
        baseline: the machine's learned detector (watch at once), or ``None`` (learn first).
        prior: a detector fitted on longer running of machines of the type, combined with
            what the machine learns (:func:`~drafttwin.diagnosis.learning.combine`).
        learn_s: how long the machine learns (default:
            :func:`~drafttwin.diagnosis.learning.learn_time` of the prior).
        post_s: the window after an alarm, s.
        has_motor: the samples carry the motor speed; without it the motor's residual is
            taken as zero (see docs/twin.md: motor-side faults and belt wear then look alike).
        phase: rows left out before the first block (see :func:`block_phase`).
    """

    def __init__(self, machine: str, channels: tuple[str, ...], rate_hz: float,
                 ratio: np.ndarray, *, baseline: FaultDetector | None = None,
                 prior: FaultDetector | None = None, learn_s: float | None = None,
                 post_s: float = POST_S, has_motor: bool = True, phase: int = 0) -> None:  # fmt: skip
        if tuple(channels) != ROLLERS:
            raise ConfigError(f"the fault detector needs the channels {', '.join(ROLLERS)}, the "
                              f"model has {', '.join(channels)}", where="--detector",
                              fix="run without a detector, or fit the model on the four rollers")  # fmt: skip
        self.machine, self.has_motor, self.rate_hz = machine, has_motor, rate_hz
        self.ratio, self.prior, self.post_s = np.asarray(ratio, dtype=np.float64), prior, post_s
        self.learn_s = learn_time(prior) if learn_s is None else float(learn_s)
        self.period_us = int(round(1e6 / rate_hz))
        if baseline is None and self.learn_s == 0:  # no learning: the prior judges as it is
            if prior is None:
                raise ConfigError("no learning and no detector to judge by", where="--learn",
                                  fix="give a detector file (twin fit-detector), or let the "
                                  "machines learn (leave out --learn 0)")  # fmt: skip
            baseline = prior
        self.detector = baseline
        self.learner: Learner | None = None if baseline is not None else self._learner()
        known = baseline if baseline is not None else prior
        self.block_s = known.block_s_ if known is not None else BLOCK_S
        self.skip = phase % max(1, int(round(self.block_s * rate_hz)))
        self.stream = self._stream()
        self.last_us: int | None = None
        self.restarts = 0
        self.learn_from_s: float | None = None  # source time of the first learned block
        # rows are pushed a block at a time (the stream gives the same numbers for any
        # pieces; a block's features are final a block later anyway)
        per = max(1, int(round(self.block_s * rate_hz)))
        self._t, self._k = np.zeros(per), 0
        self._y, self._hat = np.zeros((per, len(CHANNELS))), np.zeros((per, len(CHANNELS)))

    # ---- state ------------------------------------------------------------------------------
    @property
    def learning(self) -> bool:
        return self.detector is None

    @property
    def learn_progress(self) -> float:
        return 1.0 if self.learner is None else self.learner.progress

    @property
    def learn_left_s(self) -> float:
        """Running time still to learn, s (0 when watching)."""
        return 0.0 if self.learner is None else max(0.0, self.learn_s - self.learner.learned_s)

    def _learner(self) -> Learner:
        return Learner(self.learn_s, self.prior)

    def _stream(self) -> DiagnosisStream:
        return DiagnosisStream(1.0 / self.rate_hz, self.ratio, detector=self.detector,
                               learner=self.learner, post_s=self.post_s, machine=self.machine)  # fmt: skip

    def _took(self, step: Step) -> Step:
        if step.learned is not None:  # the learning state ended: watch with what it learned
            self.detector, self.learner = step.learned, None
        return step

    def _push(self) -> Step:
        """The rows held so far into the stream."""
        k, self._k = self._k, 0
        if k == 0:
            return Step()
        return self._took(self.stream.push(self._t[:k], self._y[:k], self._hat[:k]))

    def _end_run(self) -> Step:
        """The run's end: its last blocks and its open window (ranked with what it has). The
        next run goes on watching its active alarms for their return to normal (a belt
        replaced during a stop clears its alarm once the machine runs again)."""
        step = self._push()
        step += self._took(self.stream.finish())
        carried = self.stream.carried()
        self.stream = self._stream()
        for alarm, base in carried:
            self.stream.keep_watching(alarm, base)
        return step

    def keep_watching(self, alarm: Alarm, base: np.ndarray | None) -> None:
        """An alarm a restarted twin read back from its store, still active: watched for
        its return to normal where another run can judge it
        (:func:`~drafttwin.diagnosis.clearance.carries_over`)."""
        if carries_over(alarm, base):
            self.stream.keep_watching(alarm, base)

    def restart(self) -> Step:
        """A gap: the physics restarts, the rows go on in a new run (a new reference window;
        a learning state goes on learning)."""
        step = self._end_run()
        if self.learner is not None:
            self.learner.new_record()
        self.restarts += 1
        return step

    def relearn(self) -> Step:
        """After maintenance (an operator's command): forget the baseline and learn again."""
        step = self._end_run()
        self.detector, self.learner, self.learn_from_s = None, self._learner(), None
        self.stream = self._stream()
        step.learned = None  # (what the old run ended with is forgotten too)
        return step

    # ---- rows ------------------------------------------------------------------------------
    def add(self, row: SampleRow) -> Step:
        """One row: what it brought (alarms raised, windows closed, a learning that ended)."""
        step = Step()
        if self.last_us is not None and row.ts_us - self.last_us > 1.5 * self.period_us:
            step += self.restart()
        self.last_us = row.ts_us
        if self.skip:
            self.skip -= 1
            return step
        k = self._k
        y, yhat = self._y, self._hat
        y[k, :4], y[k, 4] = row.measured, row.motor
        yhat[k, :4], yhat[k, 4] = row.physics, row.motor_physics
        if not self.has_motor:  # no motor channel: its residual is zero by construction
            y[k, 4] = row.motor_physics
        self._t[k] = row.ts_us / 1e6
        if self.learning and self.learn_from_s is None:
            self.learn_from_s = row.ts_us / 1e6
        self._k += 1
        if self._k == len(self._t):
            step += self._push()
        return step

    def flush(self) -> Step:
        """At the end of a run: its last blocks and the open window, ranked with the blocks
        it has."""
        return self._end_run()

    def sensor_cause(self, alarm: Alarm, step: Step) -> dict[str, Any]:
        """A sensor rule's cause from the block that raised it (the ``step`` that brought the
        alarm holds it; its window sizes it later)."""
        w = step.blocks[alarm.block]
        return sensor_cause(alarm, w.lost, w.run, self.rate_hz).to_dict()


def block_phase(machine: str, rate_hz: float, block_s: float) -> int:
    """A fixed offset per machine for its block boundaries: machines started together would
    otherwise close their blocks on the same sample, and the feature rows of all of them in
    one tick add up on the latency of that tick's samples (measured with bench_twin)."""
    import zlib

    return zlib.crc32(machine.encode()) % max(1, int(round(block_s * rate_hz)))


# ---- the ranking, in a worker process ---------------------------------------------------------
_SIGNATURES: dict[str, SignatureModel] = {}
_TRAINS: dict[str, DriveTrain] = {}


def _diagnoser(key: str, train: dict[str, Any], detector: dict[str, Any],
               post_s: float) -> Diagnoser:  # fmt: skip
    """Worker side: a machine's diagnoser; the train's signatures (the costly part) built
    once per model and kept."""
    if key not in _TRAINS:
        _TRAINS[key] = DriveTrain.from_dict(train, source=f"model {key}")
        _SIGNATURES[key] = SignatureModel(_TRAINS[key])
    return Diagnoser(_TRAINS[key], FaultDetector.from_state(detector), post_s=post_s,
                     signatures=_SIGNATURES[key])  # fmt: skip


def _prepare(key: str, train: dict[str, Any]) -> None:
    """Worker side, at the twin's start: build the model's signatures and its healthy
    operating point (the first alarm then waits for the ranking only, not for a start)."""
    if key not in _TRAINS:
        _TRAINS[key] = DriveTrain.from_dict(train, source=f"model {key}")
        _SIGNATURES[key] = SignatureModel(_TRAINS[key])
    _ = _SIGNATURES[key].healthy


def _rank(key: str, train: dict[str, Any], detector: dict[str, Any], post_s: float,
          req: RankRequest) -> list[dict[str, Any]]:  # fmt: skip
    """Worker side: the top causes of a window (the offline diagnosis's own locate)."""
    _, causes = _diagnoser(key, train, detector, post_s).locate(req)
    return [c.to_dict() for c in causes[:TOP]]


Done = Callable[[RankRequest, list[dict[str, Any]] | None, str | None], None]


class Locator:
    """Runs the rankings in one worker process (started with the twin, :meth:`warm`), at most
    :data:`MAX_PENDING` at a time; ``done(request, causes, error)`` is called from the
    executor's thread. Each request carries its machine's detector (machines learn their
    own); the model's train is sent once per call (a dict of a few kB)."""

    def __init__(self) -> None:
        self.executor: ProcessPoolExecutor | None = None
        self.in_flight = 0
        self._lock = threading.Lock()  # in_flight: counted up here, down in the executor's thread
        self.models: dict[str, dict[str, Any]] = {}

    def register(self, key: str, train: DriveTrain) -> None:
        self.models[key] = train.to_dict()

    def _executor(self) -> ProcessPoolExecutor:
        if self.executor is None:
            import multiprocessing
            import os

            from drafttwin.execution.interrupt import worker_init

            # the worker ends with the twin, even one killed outright (an orphan kept 290 MB)
            self.executor = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"),
                                                initializer=worker_init, initargs=(os.getpid(),))  # fmt: skip
        return self.executor

    def warm(self) -> list[Future[None]]:
        """Start the worker and build every model's signatures there, in the background (the
        futures tell when it is ready; a second call finds them built)."""
        return [self._executor().submit(_prepare, key, train)
                for key, train in self.models.items()]  # fmt: skip

    def submit(self, key: str, detector: FaultDetector, post_s: float, req: RankRequest,
               done: Done) -> bool:  # fmt: skip
        """Queue one ranking; ``False`` (nothing queued) when :data:`MAX_PENDING` are."""
        with self._lock:
            if self.in_flight >= MAX_PENDING:
                return False
            self.in_flight += 1
        fut = self._executor().submit(_rank, key, self.models[key], detector.to_state(), post_s,
                                      req)  # fmt: skip

        def finished(f: Future[list[dict[str, Any]]]) -> None:
            with self._lock:
                self.in_flight -= 1
            exc = f.exception() if not f.cancelled() else None
            if f.cancelled() or exc is not None:
                done(req, None, "cancelled" if exc is None else f"{type(exc).__name__}: {exc}")
            else:
                done(req, f.result(), None)

        fut.add_done_callback(finished)
        return True

    def close(self) -> None:
        """End the worker now, a ranking still running with it (the caller kept its window;
        a plain ``shutdown`` would let the interpreter's exit wait for it: 3 s at a stop)."""
        if self.executor is not None:
            from drafttwin.execution.executor import stop_pool

            stop_pool(self.executor)
            self.executor = None


def alarm_detail(alarm: Alarm, causes: list[dict[str, Any]] | None = None,
                 note: str | None = None, baseline: np.ndarray | None = None) -> str:  # fmt: skip
    """The JSON stored as an alarm event's detail (and parsed back for REST and the page);
    ``baseline``: the features' baseline the alarm left (:data:`FEATURES` order), which a
    restarted twin judges its return to normal against."""
    from drafttwin._json import to_strict

    doc: dict[str, Any] = {"test": alarm.test, "rule": alarm.rule, "direction": alarm.direction,
                           "alarm_s": alarm.time_s, "onset_s": alarm.change_s}  # fmt: skip
    if causes is not None:
        doc["causes"] = [_short(c) for c in causes]
    if note is not None:
        doc["note"] = note
    if baseline is not None:
        doc["baseline"] = [float(v) for v in baseline]
    return json.dumps(to_strict(doc), allow_nan=False, separators=(",", ":"))


def stored_baseline(detail: str) -> np.ndarray | None:
    """The baseline an alarm event's detail keeps (:func:`alarm_detail`), checked: one
    finite value per feature, else ``None``."""
    try:
        doc = json.loads(detail)
        base = np.asarray(doc["baseline"], dtype=np.float64)
    except (TypeError, ValueError, KeyError):
        return None
    if base.shape != (len(FEATURES),) or not np.isfinite(base).all():
        return None
    return base


def _short(c: dict[str, Any]) -> dict[str, Any]:
    keep = ("element", "kind", "family", "severity", "interval", "parameter", "probability",
            "group")  # fmt: skip
    out = {k: c[k] for k in keep if k in c}
    if isinstance(out.get("severity"), float) and not math.isfinite(out["severity"]):
        out["severity"] = None
    return out


__all__ = [
    "LiveFaultWatch",
    "Locator",
    "block_phase",
    "detector_path",
    "load_detector",
    "save_detector",
]
