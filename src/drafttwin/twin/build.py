"""Assemble a twin service from the command line's pieces: models, mapping, sources, store."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from drafttwin.diagnosis.detect import FaultDetector
from drafttwin.errors import ConfigError
from drafttwin.mechanics import DriveTrain
from drafttwin.models.base import BaseModel
from drafttwin.twin.faultwatch import LiveFaultWatch, block_phase, detector_path, load_detector
from drafttwin.twin.live import MachineTwin, physics_train
from drafttwin.twin.service import MachineState, TwinService
from drafttwin.twin.sources.base import Source
from drafttwin.twin.sources.mapping import MachineMap, read_mapping
from drafttwin.twin.sources.opcua import OpcUaSource
from drafttwin.twin.sources.replay import ReplaySource
from drafttwin.twin.sources.spec import parse_source
from drafttwin.twin.store.db import StoreWriter, TwinStore


def load_twin_model(path: Path) -> BaseModel:
    """A model file the live twin can run (task prediction, no exogenous inputs)."""
    from drafttwin.models import OnlinePredictor
    from drafttwin.models.registry import load_model

    model = load_model(path)
    if model.task.simulation or model.task.inputs:
        OnlinePredictor(model)  # raises the streaming refusal with its fix
    return model


def build_service(
    model_path: Path,
    sources: Sequence[str],
    *,
    mapping: Path | None = None,
    store_dir: Path | None = None,
    commit_ms: float = 200.0,
    retention_s: float | None = None,
    physics: str = "reduced",
    silent_s: float = 2.0,
    on_commit: Callable[[int, int], None] | None = None,
    detector: str = "auto",
) -> TwinService:
    """The service for ``sources`` (``--source`` values), each machine with its model.

    ``detector``: ``auto`` (each model's ``MODEL.dtm.detector.json`` when it exists), ``none``,
    or a detector file for the machines of ``model_path`` (the others: auto)."""
    if detector != "auto" and detector != "none" and not Path(detector).is_file():
        raise ConfigError(f"no detector file {detector}", where="--detector",
                          fix="give the file 'drafttwin twin fit-detector' wrote, auto or none")  # fmt: skip
    if not sources:
        raise ConfigError("no source", where="--source",
                          fix="give --source replay:FILE, opcua:opc.tcp://HOST:PORT or "
                          "mqtt://HOST:PORT")  # fmt: skip
    models: dict[Path, BaseModel] = {model_path: load_twin_model(model_path)}
    channels = tuple(models[model_path].channels_)
    mapped = () if mapping is None else read_mapping(mapping, channels)
    default = MachineMap("fa320a", channels)
    built: list[Source] = [parse_source(text, default, mapped) for text in sources]
    maps: dict[str, tuple[MachineMap, str]] = {}
    no_motor: set[str] = set()
    for src in built:
        for m in src.machines:
            if m.name in maps:
                raise ConfigError(f"machine {m.name!r} comes from two sources", where="--source",
                                  fix="name each replayed machine: replay:FILE?machine=NAME")  # fmt: skip
            maps[m.name] = (m, src.spec)
            if isinstance(src, ReplaySource) and not np.isfinite(src.motor).any():
                no_motor.add(m.name)  # a file without a motor column
    store = None if store_dir is None else TwinStore(store_dir)
    states: dict[str, MachineState] = {}
    trains: dict[Path, DriveTrain] = {}
    detectors: dict[Path, tuple[FaultDetector, float] | None] = {}
    service_models: dict[str, tuple[DriveTrain, FaultDetector]] = {}
    try:
        for name, (m, spec) in maps.items():
            path = m.model or model_path
            if path not in models:
                models[path] = load_twin_model(path)
            model = models[path]
            m = replace(m, channels=tuple(model.channels_), model=path)
            if path not in trains:
                trains[path] = physics_train(model, physics)
            twin = MachineTwin(name, model, m.rate_hz, physics=physics, train=trains[path])
            twin.warm_up()
            st = MachineState(twin, m, spec, model_key=str(path))
            if path not in detectors:
                detectors[path] = _detector(path, model_path, detector)
            found = detectors[path]
            if found is not None:
                det, post_s = found
                st.watch = LiveFaultWatch(det, name, m.channels, m.rate_hz, post_s=post_s,
                                          has_motor=m.has_motor and name not in no_motor,
                                          phase=block_phase(name, m.rate_hz, det.block_s_))  # fmt: skip
                if str(path) not in service_models:
                    service_models[str(path)] = (physics_train(model, "full"), det)
            if store is not None:
                store.register_machine(name, m.channels, str(path), spec)
                st.resume_after_us = store.last_ts_us(name)
            states[name] = st
    except BaseException:
        if store is not None:
            store.close()
        raise
    for src in built:  # a restart resumes after what the store holds
        if isinstance(src, ReplaySource):  # a replay seeks there
            src.skip_to(states[src.machines[0].name].resume_after_us)
        elif isinstance(src, OpcUaSource):  # a server with history sends what it missed
            src.resume_after = {m.name: after for m in src.machines
                                if (after := states[m.name].resume_after_us) is not None}  # fmt: skip
    writer = None
    if store is not None:
        writer = StoreWriter(store, commit_ms, retention_s=retention_s, on_commit=on_commit)
    service = TwinService(states, built, writer, silent_s=silent_s)
    for key, (train, det) in service_models.items():
        service.locator.register(key, train, det)
    return service


def _detector(path: Path, main: Path, choice: str) -> tuple[FaultDetector, float] | None:
    """The fault detector of the model at ``path`` (None: the model has none, or ``none``)."""
    if choice == "none":
        return None
    if choice != "auto" and path == main:
        return load_detector(Path(choice), path)
    auto = detector_path(path)
    return load_detector(auto, path) if auto.is_file() else None


__all__ = ["build_service", "load_twin_model"]
