"""One fit of the generalisation benchmark, scored on its test records (a task for
:func:`drafttwin.execution.executor.run_tasks`, module level so worker processes can run it).

The records and their physics come through an ``.npz`` file written once by the benchmark
(:func:`save_records`), so a worker reads arrays, not pickled objects.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from drafttwin._constants import ROLLERS
from drafttwin._io import json_number, savez_atomic
from drafttwin.data.series import MeasurementSeries
from drafttwin.execution import integrity

INPUT = "supply_hz"
"""The set-point every learned model sees as an input (known in advance, in both tasks)."""


def save_records(
    path: Path,
    records: dict[str, MeasurementSeries],
    physics: dict[str, dict[str, np.ndarray]],
    sealed: bool = False,
) -> None:
    """Write every record (time, measured, true, set-point) and its physics per kind
    (``sealed``: with a checksum sidecar, for a cache)."""
    arrays: dict[str, np.ndarray] = {}
    for name, series in records.items():
        assert series.truth is not None
        arrays |= {f"{name}|time": series.time_s, f"{name}|values": series.values,
                   f"{name}|truth": series.truth, f"{name}|{INPUT}": series.inputs[INPUT]}  # fmt: skip
        for kind, mech in physics.get(name, {}).items():
            arrays[f"{name}|mech:{kind}"] = mech
    (integrity.savez_sealed if sealed else savez_atomic)(path, **arrays)


def load_records(
    path: str | Path,
) -> tuple[dict[str, MeasurementSeries], dict[str, dict[str, np.ndarray]]]:
    """What :func:`save_records` wrote (shapes checked)."""
    records: dict[str, MeasurementSeries] = {}
    physics: dict[str, dict[str, np.ndarray]] = {}
    with np.load(path, allow_pickle=False) as z:
        names = sorted({k.split("|", 1)[0] for k in z.files})
        for name in names:
            series = MeasurementSeries(z[f"{name}|time"], z[f"{name}|values"], ROLLERS,
                                       inputs={INPUT: z[f"{name}|{INPUT}"]},
                                       truth=z[f"{name}|truth"])  # fmt: skip
            records[name] = series
            physics[name] = {}
            for key in z.files:
                head, _, rest = key.partition("|")
                if head == name and rest.startswith("mech:"):
                    mech = z[key]
                    if mech.shape != series.values.shape:
                        raise ValueError(f"physics of {name} has shape {mech.shape}")
                    physics[name][rest[5:]] = mech
    return records, physics


def run_fit(cfg: dict[str, Any]) -> dict[str, Any]:
    """Fit one model on the first ``train_s`` seconds of the training record (with the
    physics ``cfg["physics"]``) and score it on each test record of ``cfg["tests"]``
    (``[record, physics kind, scenario]``): one row per scored channel."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(int(cfg.get("_threads", 1)))
    try:
        return _fit_and_score(cfg)
    finally:  # in this process (one worker) the caller's setting comes back
        torch.set_num_threads(before)


def _fit_and_score(cfg: dict[str, Any]) -> dict[str, Any]:
    from drafttwin.evaluation import protocol
    from drafttwin.models import MechanisticModel, make_model

    records, physics = load_records(cfg["_records"])
    train = records["train"]
    rows_n = int(round(cfg["train_s"] * train.sample_rate_hz))
    train = train.slice(0, min(rows_n, len(train)))
    kind = cfg["physics"]
    mech_train = physics["train"][kind][: len(train)]
    model = make_model(cfg["model"], "quick", **cfg["hyper"])
    start = time.perf_counter()
    protocol.fit(model, train, train_fraction=1.0, mechanistic=MechanisticModel(mech_train))
    fit_s = time.perf_counter() - start
    rows: list[dict[str, Any]] = []
    structure = {k: v for k, v in model.get_params().items() if k in ("structure", "fade", "skip")}
    # fade acts at prediction time only: one fit scores each variant asked for
    for fade in cfg.get("fade_variants") or [structure.get("fade")]:
        if fade is not None:
            model.set_params(fade=fade)
            structure["fade"] = fade
        for record, test_kind, scenario in cfg["tests"]:
            test = records[record]
            mech = MechanisticModel(physics[record][test_kind])
            ev = protocol.evaluate(model, test=test, mechanistic=mech, skip_rows=cfg["skip_rows"])
            for channel, m in ev.metrics.items():
                rows.append({
                    "scenario": scenario, "task": cfg["task"], "model": cfg["model"],
                    "train_s": cfg["train_s"], "seed": cfg["seed"], "channel": channel,
                    "rmse": json_number(m.rmse), "skill": json_number(m.skill),
                    "rmse_persistence": json_number(m.rmse_persistence),
                    "rmse_vs_true": json_number(m.rmse_vs_true),
                    "rmse_floor": json_number(m.rmse_floor), "physics": test_kind,
                    "n_scored": m.n_scored, "n_nan_pred": m.n_nan_pred, **structure,
                })  # fmt: skip
    return {"rows": rows, "fit_s": fit_s, "selection": dict(model.selection_),
            "model": cfg["model"], "task": cfg["task"], "train_s": cfg["train_s"],
            "seed": cfg["seed"]}  # fmt: skip
