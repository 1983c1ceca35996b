"""Fault detection and probable cause in the live path (issue 13's detector, run live).

Per machine, :class:`LiveFaultWatch` takes each processed row (in time order) and keeps one
block of measured and open-loop physics speeds (the four rollers and the motor). When a block
closes, its features come from the same function the offline diagnosis uses
(:func:`~drafttwin.diagnosis.residuals.block_features`) and go to the same CUSUM decisions
(:class:`~drafttwin.diagnosis.detect.CusumState`): per sample the cost is a copy into the block
buffer; per block one feature row and one CUSUM step. Nothing is recomputed over the history.

A sensor rule fires on every block while its fault lasts; the watch raises it once per
episode (offline, ``run(stop_at_first=False)`` lists every block). After a CUSUM alarm the
watch collects :data:`POST_S` of blocks (the shift grows by then, as
offline) and hands the mean shift to the model-based ranking
(:meth:`~drafttwin.diagnosis.diagnose.Diagnoser.rank`), which the service runs in a separate
process (:class:`Locator`): a second of SciPy fits must not hold up any machine's samples.
A sensor rule names its channel at once.

The detector's thresholds come from healthy records and are stored next to the model
(``MODEL.dtm.detector.json``, :func:`save_detector`), tied to the model file by its SHA-256 and
checked when read back (:func:`load_detector`).
"""

from __future__ import annotations

import json
import math
import threading
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drafttwin._constants import ROLLERS
from drafttwin._io import sha256_file
from drafttwin.data.series import MeasurementSeries
from drafttwin.diagnosis.detect import Alarm, CusumState, FaultDetector
from drafttwin.diagnosis.diagnose import Diagnoser, sensor_cause
from drafttwin.diagnosis.residuals import CHANNELS, LagCarry, block_features
from drafttwin.errors import ConfigError, DataError
from drafttwin.mechanics import DriveTrain
from drafttwin.twin.store.db import SampleRow

FORMAT = "drafttwin-live-detector"
VERSION = 1
POST_S = 10.0
"""Seconds of blocks after a CUSUM alarm whose mean shift is ranked (offline: up to 30 s;
live, a shorter window gives the probable cause sooner)."""
TOP = 3
"""Causes kept per alarm (the best first)."""
MAX_PENDING = 4
"""Localisations queued at once; more alarms in that time get no cause ('busy')."""


def detector_path(model: Path) -> Path:
    """Where a model's detector lives: next to it, ``MODEL.dtm.detector.json``."""
    return model.with_name(model.name + ".detector.json")


def save_detector(path: Path, detector: FaultDetector, model: Path, fitted_on: list[str],
                  post_s: float = POST_S) -> None:  # fmt: skip
    """Write the fitted detector (atomic), tied to ``model`` by its SHA-256, with the live
    post-alarm window ``post_s``."""
    from drafttwin._io import atomic_path
    from drafttwin._json import dumps_strict

    doc = {"format": FORMAT, "version": VERSION, "model_file": model.name,
           "model_sha256": sha256_file(model), "fitted_on": fitted_on, "post_s": post_s,
           "detector": detector.to_state(), "describe": detector.describe()}  # fmt: skip
    with atomic_path(path) as tmp:
        tmp.write_text(dumps_strict(doc), encoding="utf-8")


def load_detector(path: Path, model: Path) -> tuple[FaultDetector, float]:
    """Read a detector (and its post-alarm window, s) back, refusing one of another format or
    fitted for another model."""
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
    return FaultDetector.from_state(state, source=str(path)), float(post)


def plant_log_series(path: Path) -> list[MeasurementSeries] | None:
    """Each machine's record in a ``plant serve --log`` file (``None``: not a plant log), to
    fit a detector on the live plant's own healthy running."""
    from drafttwin.wire.plantlog import read_plant_log

    try:
        frame = read_plant_log(path)
    except DataError:
        return None
    out = []
    for name, rows in frame.sort_values(["machine", "seq"]).groupby("machine", sort=True):
        seq = rows["seq"].to_numpy(dtype=np.int64)
        # the plant's sample times are t0 + seq / rate: rebuilt from the counter, exactly uniform
        period_s = (
            float(np.median(np.diff(rows["ts_us"].to_numpy()))) / 1e6 if len(seq) > 1 else 0.01
        )
        out.append(MeasurementSeries(
            time_s=(seq - seq[0]) * period_s, values=rows[list(ROLLERS)].to_numpy(dtype=np.float64),
            inputs={"supply_hz": rows["supply_hz"].to_numpy(dtype=np.float64)},
            motor_rpm=rows["motor"].to_numpy(dtype=np.float64),
            metadata={"source": f"{path} (machine {name})"}))  # fmt: skip
    return out


@dataclass(frozen=True)
class Localise:
    """A request for the ranking: the alarm and its window's blocks (end times, indices, and
    features minus the baseline at the alarm, :data:`~drafttwin.diagnosis.detect.FEATURES`)."""

    machine: str
    alarm: Alarm
    time_s: np.ndarray
    blocks: np.ndarray
    deviation: np.ndarray

    @property
    def n_blocks(self) -> int:
        return len(self.blocks)

    @property
    def shift(self) -> np.ndarray:
        """The window's mean deviation (levels, then lags)."""
        return np.asarray(self.deviation.mean(axis=0))


class LiveFaultWatch:
    """The fault detector of one machine, fed row by row.

    Args:
        detector: a fitted :class:`~drafttwin.diagnosis.detect.FaultDetector`.
        machine: the machine's name.
        channels: the model's output channels (must be the four rollers).
        rate_hz: the machine's sample rate.
        has_motor: the samples carry the motor speed; without it the motor's residual is
            taken as zero (see docs/twin.md: motor-side faults and belt wear then look alike).
        phase: rows left out before the first block (see :func:`block_phase`).
    """

    def __init__(self, detector: FaultDetector, machine: str, channels: tuple[str, ...],
                 rate_hz: float, *, has_motor: bool = True, post_s: float = POST_S,
                 phase: int = 0) -> None:  # fmt: skip
        if tuple(channels) != ROLLERS:
            raise ConfigError(f"the fault detector needs the channels {', '.join(ROLLERS)}, the "
                              f"model has {', '.join(channels)}", where="--detector",
                              fix="run without a detector, or fit the model on the four rollers")  # fmt: skip
        self.detector, self.machine, self.has_motor = detector, machine, has_motor
        self.rate_hz = rate_hz
        self.per = max(1, int(round(detector.block_s_ * rate_hz)))
        self.block_s = self.per / rate_hz
        self.period_us = int(round(1e6 / rate_hz))
        self.n_ref = max(2, int(round(detector.reference_s / self.block_s)))
        self.post = max(1, int(round(post_s / self.block_s)))
        self.y = np.full((self.per, len(CHANNELS)), np.nan)
        self.yhat = np.full((self.per, len(CHANNELS)), np.nan)
        self.t = np.zeros(self.per)
        self.k = 0
        self.skip = phase % self.per
        self.last_us: int | None = None
        self.state = CusumState(detector, self.n_ref, self.block_s)
        self.lag = LagCarry()  # the angle lags go on from block to block
        self.pending: tuple[Alarm, np.ndarray, list[Window]] | None = None
        self.blocks = 0
        self.restarts = 0
        self.sensor_active: set[str] = set()
        self.levels: deque[Window] = deque(maxlen=self.post + self.n_ref)

    def restart(self) -> None:
        """A new baseline (after a gap the physics restarts: the old one no longer holds)."""
        self.state = CusumState(self.detector, self.n_ref, self.block_s)
        self.k, self.pending = 0, None
        self.lag = LagCarry()
        self.restarts += 1

    def add(self, row: SampleRow) -> tuple[list[Alarm], list[dict[str, Any]], list[Localise]]:
        """One row: the alarms of the block it closed, the sensor causes found at once and the
        localisations to run (empty lists while the block is open)."""
        if self.last_us is not None and row.ts_us - self.last_us > 1.5 * self.period_us:
            self.restart()
        self.last_us = row.ts_us
        if self.skip:
            self.skip -= 1
            return [], [], []
        k = self.k
        self.y[k, :4], self.y[k, 4] = row.measured, row.motor
        self.yhat[k, :4], self.yhat[k, 4] = row.physics, row.motor_physics
        if not self.has_motor:  # no motor channel: its residual is zero by construction
            self.y[k, 4] = row.motor_physics
        self.t[k] = row.ts_us / 1e6
        self.k += 1
        if self.k < self.per:
            return [], [], []
        self.k = 0
        return self._block()

    def _block(self) -> tuple[list[Alarm], list[dict[str, Any]], list[Localise]]:
        f = block_features(self.y, self.yhat, self.t, self.block_s, self.lag)
        lost, run = f.lost[0], f.run[0]
        level = np.concatenate([f.level[0], f.lags[0]])
        here = Window(float(f.time_s[0]), self.blocks, level)
        self.blocks += 1
        self.levels.append(here)
        alarms = self.state.update(here.time_s, level, lost, run)
        # a sensor rule fires on every block while the fault lasts: raise it once per episode
        sensor = {a.test for a in alarms if a.direction == 0}
        alarms = [a for a in alarms if a.direction != 0 or a.test not in self.sensor_active]
        self.sensor_active = sensor
        causes, requests = [], []
        if sensor:  # a stuck or dropped encoder explains a pending alarm: no machine ranking
            self.pending = None  # (as offline, Diagnoser._sensor_in_window)
        if self.pending is not None and np.isfinite(level).all():
            alarm, base, after = self.pending
            after.append(here)
            if len(after) >= self.post:
                requests.append(_request(self.machine, alarm, base, after))
                self.pending = None
        for a in alarms:
            if a.direction == 0:
                causes.append(sensor_cause(a, lost, run, self.rate_hz).to_dict())
            elif self.state.baseline_at_alarm is not None and self.pending is None and not sensor:
                self.pending = (a, self.state.baseline_at_alarm.copy(), [])
        return alarms, causes, requests

    def flush(self) -> list[Localise]:
        """At the end of a run: rank what a pending alarm collected (at least one block after
        it, else the blocks from its onset on, as offline when too little follows)."""
        if self.pending is None:
            return []
        alarm, base, after = self.pending
        self.pending = None
        if not after:
            after = [w for w in self.levels
                     if alarm.change_s < w.time_s <= alarm.time_s and np.isfinite(w.row).all()]  # fmt: skip
        if not after:
            return []
        return [_request(self.machine, alarm, base, after)]


@dataclass(frozen=True)
class Window:
    """One block of the live watch: its end time (s), index and feature row."""

    time_s: float
    block: int
    row: np.ndarray


def _request(machine: str, alarm: Alarm, base: np.ndarray, after: list[Window]) -> Localise:
    return Localise(machine, alarm, np.array([w.time_s for w in after]),
                    np.array([w.block for w in after]), np.vstack([w.row for w in after]) - base)  # fmt: skip


def block_phase(machine: str, rate_hz: float, block_s: float) -> int:
    """A fixed offset per machine for its block boundaries: machines started together would
    otherwise close their blocks on the same sample, and the feature rows of all of them in
    one tick add up on the latency of that tick's samples (measured with bench_twin)."""
    import zlib

    return zlib.crc32(machine.encode()) % max(1, int(round(block_s * rate_hz)))


# ---- the ranking, in a worker process ---------------------------------------------------------
_DIAGNOSERS: dict[str, Diagnoser] = {}


def _diagnoser(key: str, train: dict[str, Any], detector: dict[str, Any]) -> Diagnoser:
    """Worker side: the model's diagnoser, built once and kept."""
    dx = _DIAGNOSERS.get(key)
    if dx is None:
        dx = Diagnoser(DriveTrain.from_dict(train, source=f"model {key}"),
                       FaultDetector.from_state(detector))  # fmt: skip
        _DIAGNOSERS[key] = dx
    return dx


def _prepare(key: str, train: dict[str, Any], detector: dict[str, Any]) -> None:
    """Worker side, at the twin's start: build the diagnoser and its healthy operating point
    (the first alarm then waits for the ranking only, not for a process start)."""
    _ = _diagnoser(key, train, detector).signatures.healthy


def _rank(key: str, train: dict[str, Any], detector: dict[str, Any], req: Localise) -> list[dict[str, Any]]:  # fmt: skip
    """Worker side: the top causes."""
    dx = _diagnoser(key, train, detector)
    _, causes = dx.rank(req.time_s, req.blocks, req.deviation, req.alarm.change_s, req.alarm.block)
    return [c.to_dict() for c in causes[:TOP]]


class Locator:
    """Runs the rankings in one worker process (started with the twin, :meth:`warm`), at most
    :data:`MAX_PENDING` at a time; ``done(request, causes, error)`` is called from the
    executor's thread."""

    def __init__(self) -> None:
        self.executor: ProcessPoolExecutor | None = None
        self.in_flight = 0
        self._lock = threading.Lock()  # in_flight: counted up here, down in the executor's thread
        self.models: dict[str, tuple[dict[str, Any], dict[str, Any]]] = {}

    def register(self, key: str, train: DriveTrain, detector: FaultDetector) -> None:
        self.models[key] = (train.to_dict(), detector.to_state())

    def _executor(self) -> ProcessPoolExecutor:
        if self.executor is None:
            import multiprocessing

            self.executor = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"))
        return self.executor

    def warm(self) -> list[Future[None]]:
        """Start the worker and build every model's diagnoser there, in the background (the
        futures tell when it is ready; a second call finds them built)."""
        return [self._executor().submit(_prepare, key, train, det)
                for key, (train, det) in self.models.items()]  # fmt: skip

    def submit(self, key: str, req: Localise,
               done: Callable[[Localise, list[dict[str, Any]] | None, str | None], None]) -> bool:  # fmt: skip
        """Queue one ranking; ``False`` (nothing queued) when :data:`MAX_PENDING` are."""
        with self._lock:
            if self.in_flight >= MAX_PENDING:
                return False
            self.in_flight += 1
        train, det = self.models[key]
        fut = self._executor().submit(_rank, key, train, det, req)

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

    def close(self, wait: bool = False) -> None:
        if self.executor is not None:
            self.executor.shutdown(wait=wait, cancel_futures=not wait)
            self.executor = None


def alarm_detail(alarm: Alarm, causes: list[dict[str, Any]] | None = None,
                 note: str | None = None) -> str:  # fmt: skip
    """The JSON stored as an alarm event's detail (and parsed back for REST and the page)."""
    from drafttwin._json import to_strict

    doc: dict[str, Any] = {"test": alarm.test, "direction": alarm.direction,
                           "alarm_s": alarm.time_s, "onset_s": alarm.change_s}  # fmt: skip
    if causes is not None:
        doc["causes"] = [_short(c) for c in causes]
    if note is not None:
        doc["note"] = note
    return json.dumps(to_strict(doc), allow_nan=False, separators=(",", ":"))


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
