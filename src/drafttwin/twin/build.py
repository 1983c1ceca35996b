"""Assemble a twin service from the command line's pieces: models, mapping, sources, store."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from drafttwin._constants import ROLLERS
from drafttwin._io import sha256_file
from drafttwin.diagnosis.detect import FaultDetector
from drafttwin.diagnosis.residuals import roller_ratio
from drafttwin.diagnosis.stream import BLOCK_S, POST_S
from drafttwin.errors import ConfigError, DataError
from drafttwin.mechanics import DriveTrain
from drafttwin.models.base import BaseModel
from drafttwin.sliver.levelwatch import SEARCH_MM, WINDOW_M
from drafttwin.twin.faultwatch import LiveFaultWatch, block_phase, detector_path, load_detector
from drafttwin.twin.live import MachineTwin, physics_train
from drafttwin.twin.service import MachineState, TwinService
from drafttwin.twin.sources.base import Source
from drafttwin.twin.sources.mapping import MachineMap, read_mapping
from drafttwin.twin.sources.opcua import OpcUaSource
from drafttwin.twin.sources.replay import ReplaySource
from drafttwin.twin.sources.spec import parse_source
from drafttwin.twin.store.baselines import Baseline, BaselineStore
from drafttwin.twin.store.db import StoreWriter, TwinStore
from drafttwin.twin.store.history import stored_alarm_events
from drafttwin.wire.identity import MachineIdentity


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
    learn_s: float | None = None,
    level_window_m: float = WINDOW_M,
    level_search_mm: float = SEARCH_MM,
) -> TwinService:
    """The service for ``sources`` (``--source`` values), each machine with its model.

    ``detector``: ``auto`` (every machine learns its healthy state, on top of its model's
    ``MODEL.dtm.detector.json`` as a prior when it exists; a baseline it learned before is
    read back from the store), ``none``, or a detector file as the prior of the machines of
    ``model_path`` (the others: auto). ``learn_s``: how long a machine learns (default: what
    the detector needs, :func:`~drafttwin.diagnosis.learning.learn_time`). ``level_window_m``:
    delivered sliver per recommendation of a machine's leveller; ``level_search_mm``: action
    points searched either side of its setting (``sliver level --search``)."""
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
    served = {m.name for src in built for m in src.machines}
    unused = [m.name for m in mapped if m.name not in served]
    replays = all(isinstance(src, ReplaySource) for src in built)  # (a hall's shard: a subset)
    if unused and replays:  # a replay names its one machine itself: the others are ignored
        raise ConfigError(f"--mapping names {', '.join(unused)}, which no --source serves",
                          source=mapping, where="--mapping",
                          fix="name the replayed machine as mapped (replay:FILE?machine=NAME), "
                          "or leave that machine out of the mapping")  # fmt: skip
    maps: dict[str, tuple[MachineMap, str]] = {}
    no_motor: set[str] = set()
    identities: dict[str, MachineIdentity] = {}
    for src in built:
        for m in src.machines:
            if m.name in maps:
                both = (maps[m.name][1], src.spec)
                live = not (isinstance(src, ReplaySource)
                            and all(s.startswith("replay:") for s in both))  # fmt: skip
                raise ConfigError(
                    f"machine {m.name!r} comes from two sources ({both[0]} and {both[1]})",
                    where="--source",
                    fix="a live source serves every machine of --mapping (fa320a without one): "
                    "give each server's machines their own names in --mapping and split them "
                    "with ?shard=I/K, or run one twin per server" if live else
                    "name each replayed machine: replay:FILE?machine=NAME")  # fmt: skip
            maps[m.name] = (m, src.spec)
            if isinstance(src, ReplaySource) and not np.isfinite(src.motor).any():
                no_motor.add(m.name)  # a file without a motor column
            if isinstance(src, ReplaySource) and src.identity is not None:
                identities[m.name] = src.identity  # the recorded machine, from the sidecar
    store = None if store_dir is None else TwinStore(store_dir)
    baselines = None if store_dir is None else BaselineStore(Path(store_dir) / "baselines")
    states: dict[str, MachineState] = {}
    trains: dict[Path, DriveTrain] = {}
    detectors: dict[Path, tuple[FaultDetector, float, dict[str, Any]] | None] = {}
    service_models: dict[str, DriveTrain] = {}
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
            st = MachineState(twin, m, spec, model_key=str(path), model_sha256=sha256_file(path),
                              identity=identities.get(name))  # fmt: skip
            # auto watches the machines of a drawing frame's model (the four rollers); a file
            # given for another model is refused (LiveFaultWatch names the channels it needs)
            if detector != "none" and (detector != "auto" or tuple(model.channels_) == ROLLERS):
                if path not in detectors:
                    detectors[path] = _detector(path, model_path, detector)
                _watch(st, detectors[path], baselines, learn_s,
                       has_motor=m.has_motor and name not in no_motor)  # fmt: skip
                if str(path) not in service_models:
                    service_models[str(path)] = physics_train(model, "full")
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
    service = TwinService(states, built, writer, silent_s=silent_s, level_window_m=level_window_m,
                          level_search_mm=level_search_mm)  # fmt: skip
    service.baselines = baselines
    if store is not None:  # the alarms the run before left unacknowledged or active
        service.faults.restore(stored_alarm_events(store.con, list(states)))
    for key, train in service_models.items():
        service.locator.register(key, train)
    for st in states.values():  # a baseline the store kept is events' first line
        if st.watch is not None:
            service.announce(st)
    return service


def _watch(
    st: MachineState,
    found: tuple[FaultDetector, float, dict[str, Any]] | None,
    baselines: BaselineStore | None,
    learn_s: float | None,
    *,
    has_motor: bool,
) -> None:
    """The machine's diagnosis: its stored baseline when it is this machine's and this
    model's (else it learns), the model's detector file as the prior."""
    prior, post_s, origin = found if found is not None else (None, POST_S, None)
    name, m, twin = st.twin.name, st.mapping, st.twin
    st.prior = origin
    try:
        kept = None if baselines is None else baselines.load(name)
    except DataError as exc:  # damaged: set aside (kept for a look), the machine learns again
        assert baselines is not None
        kept, st.refused = None, f"damaged, set aside as {baselines.set_aside(name).name} ({exc})"
    else:
        st.refused = _refusal(kept, st)
    if st.refused is None:
        st.baseline = kept
    known = st.baseline.detector if st.baseline is not None else prior
    block_s = known.block_s_ if known is not None else BLOCK_S
    st.watch = LiveFaultWatch(name, m.channels, m.rate_hz, roller_ratio(twin.train),
                              baseline=None if st.baseline is None else st.baseline.detector,
                              prior=prior, learn_s=learn_s, post_s=post_s, has_motor=has_motor,
                              phase=block_phase(name, m.rate_hz, block_s))  # fmt: skip
    if baselines is not None and st.watch.learner is not None:  # go on learning, if kept
        st.watch.learn_from_s = baselines.load_learning(name, st.identity, st.model_sha256,
                                                        st.watch.learner)  # fmt: skip


def _refusal(kept: Baseline | None, st: MachineState) -> str | None:
    """Why a stored baseline does not judge this machine (None: it does, or there is none)."""
    if kept is None:
        return None
    if kept.model_sha256 != st.model_sha256:
        return "its baseline was learned with another model file"
    if kept.identity is not None and st.identity is not None and kept.identity != st.identity:
        return f"its baseline was learned on {kept.identity}, the machine is {st.identity}"
    return None


def _detector(path: Path, main: Path,
              choice: str) -> tuple[FaultDetector, float, dict[str, Any]] | None:  # fmt: skip
    """The detector file of the model at ``path``, the machines' prior (None: none)."""
    if choice == "none":
        return None
    if choice != "auto" and path == main:
        return load_detector(Path(choice), path)
    auto = detector_path(path)
    return load_detector(auto, path) if auto.is_file() else None


__all__ = ["build_service", "load_twin_model"]
