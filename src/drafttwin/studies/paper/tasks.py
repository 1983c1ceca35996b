"""Study tasks: module-level functions ``task(config) -> result`` run by the executor.

Every task reads the prepared data from ``config["_data"]`` (an .npz written by
:mod:`drafttwin.studies.paper.prepare`) and writes large artefacts (a fitted GRU, predictions)
under ``config["_artifacts"]``; both are context, not part of the task's identity.
Workers use one PyTorch thread each, so parallel tasks do not oversubscribe the cores.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import torch

from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import DrafttwinError
from drafttwin.evaluation import protocol
from drafttwin.execution import integrity
from drafttwin.execution.store import task_key
from drafttwin.models import BaseModel, MechanisticModel, make_model
from drafttwin.models.estimators.datadriven import GRUModel
from drafttwin.models.estimators.mdsl import MDSL
from drafttwin.models.training import History
from drafttwin.studies.paper.prepare import PreparedData

T = TypeVar("T")


def _setup(config: dict[str, Any]) -> PreparedData:
    torch.set_num_threads(1)
    return _checked(config["_data"], PreparedData.load)


def _checked(path: str | Path, loader: Callable[[Path], T]) -> T:
    """A cache file the study wrote this run or checked when it reused the task that wrote
    it; damaged since then (it is reported and discarded), the task fails: a rerun
    recomputes it."""
    value = integrity.read_checked(path, loader)
    if value is None:
        raise DrafttwinError("a cache file was damaged during the run", source=path,
                             fix="run the same command again: it is recomputed")  # fmt: skip
    return value


def _artifact(config: dict[str, Any], data: PreparedData, suffix: str) -> Path:
    folder = Path(config["_artifacts"])
    folder.mkdir(parents=True, exist_ok=True)
    return folder / f"{task_key(config, data.digest)[:24]}{suffix}"


def _history(model: BaseModel) -> History:
    """The training history of a model that trains a network."""
    history = getattr(model, "history_", None)
    if not isinstance(history, History):
        raise TypeError(f"{type(model).__name__} trains no network, so it has no history")
    return history


METRIC_SCHEMA = "channel-metrics-3"
"""Names the fields of :func:`score`'s rows (``rmse``, ``rmse_floor``, ``rel_threshold``, ...);
changes whenever they change, so the study does not reuse results scored differently."""


def score(data: PreparedData, pred: np.ndarray, model: BaseModel) -> dict[str, dict[str, Any]]:
    """Per-roller metrics of ``model``'s predictions over the whole record, scored by the
    evaluation protocol on the test part (JSON-safe: None where not computable), with the
    accuracy limits on plant data (``rmse_vs_true``, ``sensor_rmse``, ``true_error_ratio``,
    ``rmse_floor``; :class:`drafttwin.evaluation.metrics.ChannelMetrics`)."""
    result = protocol.score(data.split(), pred[data.n_train :], model)
    rows = result.rows()
    for row in rows.values():
        row.pop("channel", None)
    return rows


def grid_point(config: dict[str, Any]) -> dict[str, Any]:
    """One grid-search configuration: fit on the training part, return the validation loss."""
    data = _setup(config)
    y = data.inputs[: data.n_train]
    start = 0 if config["train_samples"] is None else max(0, len(y) - config["train_samples"])
    series = MeasurementSeries(data.time_s[start : data.n_train], y[start:])
    model = make_model(config["net"], config["model_profile"], window=config["window"],
                       hidden=config["hidden"], layers=config["layers"], lr=config["lr"],
                       epochs=config["epochs"], patience=config["patience"], seed=config["seed"],
                       quiet=True)  # fmt: skip
    t0 = time.perf_counter()
    model.fit(series)
    hist = _history(model)
    losses = hist.val_loss or hist.train_loss
    return {"val_loss": float(min(losses)), "epochs": len(hist.train_loss),
            "wall_s": time.perf_counter() - t0}  # fmt: skip


def data_model(config: dict[str, Any]) -> dict[str, Any]:
    """The GRU data-driven model: cross-fitted on the training part (honest residuals for the
    MD models) and refitted on all of it (the comparison's GRU); saves both for reuse."""
    data = _setup(config)
    mdsl = make_model("md-s-l", config["model_profile"], seed=config["seed"], quiet=True,
                      **config["hyper"])  # fmt: skip
    assert isinstance(mdsl, MDSL)
    train = data.series().slice(0, data.n_train)
    t0 = time.perf_counter()
    oof = mdsl.fit_data_model(train)
    gru = mdsl.data_model_
    gru_path = _artifact(config, data, ".gru.dtm")
    with integrity.sealed_path(gru_path) as tmp:
        gru.save(tmp)
    oof_path = _artifact(config, data, ".oof.npy")
    integrity.save_npy_sealed(oof_path, oof)
    pred = gru.predict_values(data.series())
    pred_path = _artifact(config, data, ".pred.npy")
    integrity.save_npy_sealed(pred_path, pred)
    return {"gru_path": str(gru_path), "oof_path": str(oof_path), "pred_path": str(pred_path),
            "blocks": [list(b) for b in mdsl.crossfit_blocks_], "metrics": score(data, pred, gru),
            "epochs": len(gru.history_.train_loss), "wall_s": time.perf_counter() - t0}  # fmt: skip


def hybrid(config: dict[str, Any]) -> dict[str, Any]:
    """Fit one residual hybrid (parallel, md-s-l, md-l, md-s, md-s-l+d) on the nominal or,
    with ``config["physics"] == "calibrated"``, the calibrated physics, and score it."""
    data = _setup(config)
    # the paper's comparison scores the residual models themselves: none falls back on the
    # physics alone (one step ahead on roller data, noise-like residuals would make it do so)
    model = make_model(config["model"], config["model_profile"], seed=config["seed"], quiet=True,
                       **{"fallback": False, **config["hyper"]})  # fmt: skip
    train = data.series().slice(0, data.n_train)
    if isinstance(model, MDSL):  # the study's cross-fitted GRU, shared by its MD models
        dm = config["_data_model"]
        oof = _checked(dm["oof_path"], lambda p: integrity.load_array(p, train.values.shape))
        model.use_data_model(_checked(dm["gru_path"], GRUModel.load), oof, dm["blocks"])
    mech = data.physics(config.get("physics", "nominal"))
    t0 = time.perf_counter()
    model.fit(train, MechanisticModel(mech[: data.n_train]))
    pred = model.predict_values(data.series(), MechanisticModel(mech))
    result = {"metrics": score(data, pred, model), "epochs": len(_history(model).train_loss),
              "wall_s": time.perf_counter() - t0}  # fmt: skip
    if config.get("save_predictions"):
        path = _artifact(config, data, ".pred.npy")
        integrity.save_npy_sealed(path, pred)
        result["pred_path"] = str(path)
    return result
