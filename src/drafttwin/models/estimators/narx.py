"""NARX: the data-driven models (GRU/LSTM) in simulation mode.

A window of ``[y, dy, u]`` (output levels, their per-sample changes, inputs) at rows
``T-W .. T-1`` predicts the change ``dy(T)``. The network is trained one step ahead on
measured data and run free from its own outputs after each record's measured start. Its output
bias is re-fitted in closed form after training (:func:`~drafttwin.models.training.debias_head`),
because a free run sums the predicted changes and any constant error in them becomes a drift.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np
import torch

from drafttwin.data.scaling import MinMaxScaler
from drafttwin.models.estimators.features import fit_scaler, scale_inputs
from drafttwin.models.estimators.networks import RecurrentRegressor
from drafttwin.models.estimators.windows import (
    causal_ffill,
    finite_rows,
    footprint_outside,
    gather_windows,
    increments,
    target_rows,
)
from drafttwin.models.training import (
    FitProgress,
    History,
    Training,
    debias_head,
    train_network,
)
from drafttwin.models.training.compute import cpu_threads


class NarxModel(Protocol):
    """What the NARX functions need of a recurrent estimator."""

    window: int
    seed: int
    training: Training
    net_: RecurrentRegressor
    sim_scalers_: dict[str, MinMaxScaler]
    history_: History

    def _build(self, n_out: int) -> RecurrentRegressor: ...

    def _device(self) -> str: ...


def narx_scalers(y: np.ndarray, u: np.ndarray, starts: Sequence[int]) -> dict[str, MinMaxScaler]:
    """Scalers of the NARX channels fitted on training values (NaN rows ignored)."""
    yf = causal_ffill(y, starts)
    out = {
        "y": fit_scaler(y, "outputs"),
        "dy": fit_scaler(increments(yf, starts), "output changes"),
    }
    if u.shape[1]:
        out["u"] = fit_scaler(u, "inputs")
    return out


def narx_features(
    scalers: dict[str, MinMaxScaler], y: np.ndarray, u: np.ndarray, starts: Sequence[int] = (0,)
) -> np.ndarray:
    """NARX channels ``[y, dy, u]`` scaled, ``(n, 2 * outputs + inputs)``."""
    yf = causal_ffill(y, starts)
    parts = [scalers["y"].transform(yf), scalers["dy"].transform(increments(yf, starts))]
    parts.append(scale_inputs(scalers.get("u"), u, tuple(starts)))
    return np.hstack(parts)


def measured_changes(y: np.ndarray, starts: Sequence[int]) -> np.ndarray:
    """``y(T) - y(T-1)`` where both are measured in the same record, else NaN."""
    dy = np.full_like(y, np.nan)
    dy[1:] = y[1:] - y[:-1]
    dy[[s for s in starts if 0 < s < len(y)]] = np.nan
    return dy


def fit_narx(
    model: NarxModel,
    y: np.ndarray,
    u: np.ndarray,
    starts: Sequence[int],
    *,
    exclude: tuple[int, int] | None,
    progress: FitProgress | None,
    stage: str,
) -> None:
    """Fit the NARX network of ``model`` one step ahead: window ``[y, dy, u]`` at rows
    ``T-W .. T-1`` -> scaled ``dy(T)``. ``exclude`` holds out rows as in cross-fitting."""
    y_in = np.array(y, dtype=np.float64, copy=True)
    u_fit = np.array(u, dtype=np.float64, copy=True)
    if exclude is not None:
        y_in[exclude[0] : exclude[1]] = np.nan
        u_fit[exclude[0] : exclude[1]] = np.nan
    scalers = narx_scalers(y_in, u_fit, starts)
    feats = narx_features(scalers, y_in, u, starts)
    rows = target_rows(len(y_in), model.window, 1, starts)
    if exclude is not None:
        rows = rows[footprint_outside(rows, model.window, 1, exclude)]
    x = gather_windows(feats, rows, model.window, 1)
    t = scalers["dy"].transform(measured_changes(y_in, starts))[rows]
    ok = finite_rows(x, t)
    net = model._build(y.shape[1])
    history = train_network(net, x[ok], t[ok], model.training, seed=model.seed,
                            progress=progress, stage=stage)  # fmt: skip
    debias_head(net, x[ok], t[ok], None, model._device())
    model.net_, model.history_, model.sim_scalers_ = net, history, scalers


def run_narx(
    model: NarxModel,
    y: np.ndarray,
    u: np.ndarray,
    segments: Sequence[tuple[int, int]],
    init: int,
) -> np.ndarray:
    """Free runs of a fitted NARX model, ``(n, outputs)`` in output units.

    Each segment ``[a, b)`` (a record, or a held-out block of one) starts from its measured
    rows ``a .. a+init-1`` (copied into the result) and runs free from its own outputs after
    them; segments run side by side as one batch. Rows outside the segments are NaN, as is a
    segment whose initialisation rows hold no measurement.
    """
    sc, w = model.sim_scalers_, model.window
    n_out = y.shape[1]
    out = np.full(y.shape, np.nan)
    runs = []
    for a, b in segments:
        seg_y = np.full((b - a, n_out), np.nan)
        seg_y[:init] = causal_ffill(y[a : a + init])
        if b - a > init and np.isfinite(seg_y[init - 1]).all():
            runs.append((a, b, seg_y))
        elif b - a <= init:
            out[a:b] = seg_y[: b - a]
    if not runs:
        return out
    longest = max(b - a for a, b, _ in runs)
    feats = np.zeros((len(runs), longest, 2 * n_out + u.shape[1]), dtype=np.float32)
    for s, (a, b, seg_y) in enumerate(runs):
        feats[s, : b - a] = narx_features(sc, seg_y, u[a:b])  # u rows known, y rows < init
    _free_run(model, [seg for _, _, seg in runs], feats, init, w, n_out)
    for a, b, seg_y in runs:
        out[a:b] = seg_y
    return out


def _free_run(
    model: NarxModel, ys: list[np.ndarray], feats: np.ndarray, init: int, w: int, n_out: int
) -> None:
    """Step the NARX net row by row, writing its outputs into each run's ``ys[s]``."""
    sc = model.sim_scalers_
    lengths = np.array([len(seg) for seg in ys])
    net = model.net_
    device = next(net.parameters()).device
    with cpu_threads(device, limit=1), torch.inference_mode():
        for t in range(init, int(lengths.max())):
            active = np.flatnonzero(lengths > t)
            x = torch.as_tensor(feats[active, t - w : t], device=device)
            d = sc["dy"].inverse_transform(net(x).cpu().numpy().astype(np.float64))
            for k, s in enumerate(active):
                ys[s][t] = ys[s][t - 1] + d[k]
            level = sc["y"].transform(np.stack([ys[s][t] for s in active]))
            feats[active, t, :n_out] = level
            feats[active, t, n_out : 2 * n_out] = sc["dy"].transform(d)


def narx_state(scalers: dict[str, MinMaxScaler]) -> dict[str, Any]:
    return {k: v.to_dict() for k, v in scalers.items()}


def narx_restore(state: dict[str, Any]) -> dict[str, MinMaxScaler]:
    return {k: MinMaxScaler.from_dict(v) for k, v in state.items()}
