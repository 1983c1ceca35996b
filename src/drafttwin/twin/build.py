"""Assemble a twin service from the command line's pieces: models, mapping, sources, store."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

from drafttwin.errors import ConfigError
from drafttwin.mechanics import DriveTrain
from drafttwin.models.base import BaseModel
from drafttwin.twin.live import MachineTwin, physics_train
from drafttwin.twin.mapping import MachineMap, read_mapping
from drafttwin.twin.service import MachineState, TwinService
from drafttwin.twin.sources import OpcUaSource, ReplaySource, Source, parse_source
from drafttwin.twin.store import StoreWriter, TwinStore


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
) -> TwinService:
    """The service for ``sources`` (``--source`` values), each machine with its model."""
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
    for src in built:
        for m in src.machines:
            if m.name in maps:
                raise ConfigError(f"machine {m.name!r} comes from two sources", where="--source",
                                  fix="name each replayed machine: replay:FILE?machine=NAME")  # fmt: skip
            maps[m.name] = (m, src.spec)
    store = None if store_dir is None else TwinStore(store_dir)
    states: dict[str, MachineState] = {}
    trains: dict[Path, DriveTrain] = {}
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
            st = MachineState(twin, m, spec)
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
    return TwinService(states, built, writer, silent_s=silent_s)


__all__ = ["build_service", "load_twin_model"]
