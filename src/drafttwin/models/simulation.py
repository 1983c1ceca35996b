"""Tasks and channels: one-step prediction or free-run simulation, any output/input channels.

Every estimator has four hyperparameters handled here (all optional, defaults give the
original roller-speed behaviour):

* ``task``: ``"prediction"`` (SPEC section 2: row ``T`` uses measured outputs up to
  ``T - horizon``) or ``"simulation"`` (free run: only the first ``init_samples`` measured rows
  of the series are used; :meth:`BaseModel.predict` blanks every later measured output before
  any model code sees it);
* ``outputs``: names of the output channels (``series.channels``); ``None`` = the four rollers;
* ``inputs``: exogenous input channels taken from ``series.inputs`` (e.g. a drive voltage),
  known at every row in both tasks;
* ``init_samples``: measured rows a simulation may use (default: the longest window).

Simulation mode, per model (see ``docs/emps.md``):

* mechanistic: the source's open-loop simulation, unchanged;
* persistence: the last measured value of the initialisation window, held;
* gru / lstm (NARX): a window of ``[y, dy, u]`` (levels, per-sample changes, inputs) at rows
  ``T-W .. T-1`` predicts the change ``dy(T)``; trained one step ahead on measured data, run
  free from its own outputs;
* parallel / md-s-l: windows of ``[u, yhat_m, dyhat_m]`` (md-s-l adds the per-sample change
  of the data-driven model's free run, ``dyhat_d``) at rows ``T-W+1 .. T`` predict the mechanistic
  residual; with ``skip`` its per-sample change, accumulated from the measured residual at the
  end of the initialisation window (no measured residual after it is ever used); early
  stopping then uses the free-run drift over the validation part.

Networks that predict changes get their output bias re-fitted in closed form on the training
samples after training (:func:`debias_head`): a summed free run turns any constant error in the
changes into a drift.

This module holds the channel plumbing and the NARX free run; :mod:`.hybrid` and
:mod:`.mdsl` assemble the residual channels.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from torch import nn

from drafttwin import ROLLERS
from drafttwin.data.scaling import MinMaxScaler
from drafttwin.errors import ConfigError, DataError
from drafttwin.models.training import FitProgress, predict_network, split_sizes, train_network
from drafttwin.models.windows import (
    causal_ffill,
    finite_rows,
    footprint_outside,
    gather_windows,
    target_rows,
)

if TYPE_CHECKING:
    from drafttwin.data.series import MeasurementSeries
    from drafttwin.models.datadriven import _RecurrentModel

TASKS = ("prediction", "simulation")
"""Accepted values of the ``task`` hyperparameter."""


def _names_ok(v: Any, *, allow_empty: bool) -> bool:
    if not isinstance(v, tuple | list) or (not v and not allow_empty):
        return False
    return all(isinstance(s, str) and s for s in v) and len(set(v)) == len(v)


TASK_CHECKS: dict[str, tuple[Any, str]] = {
    "task": (lambda v: v in TASKS, f"one of {', '.join(TASKS)}"),
    "outputs": (
        lambda v: v is None or _names_ok(v, allow_empty=False),
        "None or a non-empty tuple of distinct channel names",
    ),
    "inputs": (
        lambda v: _names_ok(v, allow_empty=True),
        "a tuple of distinct set-point channel names (may be empty)",
    ),
    "init_samples": (
        lambda v: v is None or (isinstance(v, int) and not isinstance(v, bool) and v >= 1),
        "None or an integer >= 1 (samples)",
    ),
}
"""Checks of the task hyperparameters, merged into the estimators' parameter checks."""


# ----- channels ------------------------------------------------------------------------------
def output_names(model: object) -> tuple[str, ...]:
    """The output channels of a model: its ``outputs`` or the four rollers."""
    outputs = getattr(model, "outputs", None)
    return ROLLERS if outputs is None else tuple(outputs)


def input_names(model: object) -> tuple[str, ...]:
    return tuple(getattr(model, "inputs", ()) or ())


def is_simulation(model: object) -> bool:
    return getattr(model, "task", "prediction") == "simulation"


def init_rows(model: object) -> int:
    """Measured rows a simulation may use: ``init_samples``, else the longest window."""
    init = getattr(model, "init_samples", None)
    if init is not None:
        return int(init)
    return max(int(getattr(model, "window", 1)), int(getattr(model, "data_window", 0)), 1)


def check_task_params(model: object) -> None:
    """Cross-parameter checks of the task hyperparameters (after the per-field checks)."""
    clash = set(input_names(model)) & set(output_names(model))
    if clash:
        raise ConfigError(
            f"channel(s) {sorted(clash)} are both inputs and outputs of {type(model).__name__}",
            fix="an exogenous input must not be an output channel",
        )
    if not is_simulation(model):
        return
    if getattr(model, "horizon", 1) != 1:
        raise ConfigError(
            f"horizon={model.horizon} is only meaningful for task='prediction'",  # type: ignore[attr-defined]
            fix="leave horizon at 1 for task='simulation' (a free run predicts every row)",
        )
    init = init_rows(model)
    for key in ("window", "data_window"):
        w = getattr(model, key, None)
        if w is not None and w > init:
            raise ConfigError(
                f"{key}={w} is longer than the {init} measured rows a simulation may use",
                fix=f"set init_samples >= {w} or shorten {key}",
            )


def input_matrix(series: MeasurementSeries, names: Sequence[str]) -> np.ndarray:
    """Exogenous inputs ``(n, len(names))`` from ``series.inputs`` (their own units)."""
    cols = []
    for name in names:
        if name not in series.inputs:
            raise DataError(
                f"the series has no input channel {name!r} (set-points: "
                f"{sorted(series.inputs) or 'none'})",
                fix="put the exogenous input into MeasurementSeries.inputs under that name",
            )
        col = np.asarray(series.inputs[name], dtype=np.float64)
        if col.shape != (len(series),):
            raise DataError(f"input channel {name!r} has shape {col.shape}, not ({len(series)},)")
        cols.append(col)
    return np.column_stack(cols) if cols else np.zeros((len(series), 0))


def blank_after_init(series: MeasurementSeries, init: int) -> MeasurementSeries:
    """The series with every measured output after the first ``init`` rows set to NaN: what a
    simulation may see (inputs and set-points are kept: they are known in advance)."""
    rpm = np.array(series.values, dtype=np.float64, copy=True)
    rpm[init:] = np.nan
    return series.with_values(rpm)


def increments(x: np.ndarray) -> np.ndarray:
    """Per-sample change ``x(T) - x(T-1)`` (row 0: 0), same units and shape as ``x``."""
    x = np.asarray(x, dtype=np.float64)
    out = np.zeros_like(x)
    out[1:] = x[1:] - x[:-1]
    return out


def fit_scaler(values: np.ndarray, what: str) -> MinMaxScaler:
    """A MinMaxScaler fitted on ``values``; a column without finite values is a DataError."""
    try:
        return MinMaxScaler().fit(values)
    except ValueError as exc:
        raise DataError(
            f"cannot scale the {what}: a column has no finite training value",
            fix="check the training part for channels without any measurement",
        ) from exc


def scale_inputs(scaler: MinMaxScaler | None, u: np.ndarray) -> np.ndarray:
    """Scaled, causally filled inputs ``(n, k)`` (``(n, 0)`` without inputs)."""
    if scaler is None or u.shape[1] == 0:
        return np.zeros((u.shape[0], 0))
    return causal_ffill(scaler.transform(u))


# ----- NARX: the data-driven models in simulation mode ------------------------------------
def narx_scalers(y: np.ndarray, u: np.ndarray) -> dict[str, MinMaxScaler]:
    """Scalers of the NARX channels fitted on training values (NaN rows ignored)."""
    yf = causal_ffill(y)
    out = {"y": fit_scaler(y, "outputs"), "dy": fit_scaler(increments(yf), "output changes")}
    if u.shape[1]:
        out["u"] = fit_scaler(u, "inputs")
    return out


def narx_features(scalers: dict[str, MinMaxScaler], y: np.ndarray, u: np.ndarray) -> np.ndarray:
    """NARX channels ``[y, dy, u]`` scaled, ``(n, 2 * outputs + inputs)``."""
    yf = causal_ffill(y)
    parts = [scalers["y"].transform(yf), scalers["dy"].transform(increments(yf))]
    parts.append(scale_inputs(scalers.get("u"), u))
    return np.hstack(parts)


def fit_narx(
    model: _RecurrentModel,
    y: np.ndarray,
    u: np.ndarray,
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
    scalers = narx_scalers(y_in, u_fit)
    feats = narx_features(scalers, y_in, u)
    rows = target_rows(len(y_in), model.window, 1)
    if exclude is not None:
        rows = rows[footprint_outside(rows, model.window, 1, exclude)]
    x = gather_windows(feats, rows, model.window, 1)
    dy = np.full_like(y_in, np.nan)
    dy[1:] = y_in[1:] - y_in[:-1]  # measured changes only: no target across a gap
    t = scalers["dy"].transform(dy)[rows]
    ok = finite_rows(x, t)
    net = model._build()
    history = train_network(
        net, x[ok], t[ok], model._train_config(model.seed), progress=progress, stage=stage
    )
    debias_head(net, x[ok], t[ok], None, model.device)
    model.scaler_, model.net_, model.history_ = scalers["y"], net, history
    model.input_scaler_ = scalers.get("u")
    model.sim_scalers_ = scalers


def run_narx(
    model: _RecurrentModel, y: np.ndarray, u: np.ndarray, segments: Sequence[tuple[int, int]]
) -> np.ndarray:
    """Free runs of a fitted NARX model, ``(n, outputs)`` in output units.

    Each segment ``[a, b)`` starts from its measured rows ``a .. a+I-1`` (``I`` =
    :func:`init_rows`; they are copied into the result) and runs free from its own outputs
    after them; segments run side by side as one batch. Rows outside the segments are NaN, as
    is a segment whose initialisation rows hold no measurement.
    """
    sc, init, w = model.sim_scalers_, init_rows(model), model.window
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
    _free_run(model, runs, feats, init, w, n_out)
    for a, b, seg_y in runs:
        out[a:b] = seg_y
    return out


def _free_run(model, runs, feats: np.ndarray, init: int, w: int, n_out: int) -> None:
    """Step the NARX net row by row, writing its outputs into each run's ``seg_y``."""
    sc = model.sim_scalers_
    lengths = np.array([b - a for a, b, _ in runs])
    ys = [seg_y for _, _, seg_y in runs]
    net = model.net_
    device = next(net.parameters()).device
    with torch.inference_mode():
        for t in range(init, int(lengths.max())):
            active = np.flatnonzero(lengths > t)
            x = torch.as_tensor(feats[active, t - w : t], device=device)
            d = sc["dy"].inverse_transform(net(x).cpu().numpy().astype(np.float64))
            for k, s in enumerate(active):
                ys[s][t] = ys[s][t - 1] + d[k]
            level = sc["y"].transform(np.stack([ys[s][t] for s in active]))
            feats[active, t, :n_out] = level
            feats[active, t, n_out : 2 * n_out] = sc["dy"].transform(d)


def narx_state(model: _RecurrentModel) -> dict[str, Any]:
    return {k: v.to_dict() for k, v in model.sim_scalers_.items()}


def narx_restore(state: dict[str, Any]) -> dict[str, MinMaxScaler]:
    return {k: MinMaxScaler.from_dict(v) for k, v in state.items()}


def drift_validator(
    x: np.ndarray,
    target: np.ndarray,
    extra: np.ndarray | None,
    val_fraction: float,
    stride: int,
) -> Callable[[nn.Module], float] | None:
    """Early-stopping criterion of an accumulating residual model: the mean squared drift of
    the accumulated predicted changes over the validation part, in scaled units squared.

    ``x``, ``target``, ``extra``: the training samples in chronological order, before
    ``stride`` subsampling; the validation part is the same time span :func:`train_network`
    holds out (after its last strided training sample), at full resolution. ``None`` when
    there is no validation part.
    """
    n_strided = len(range(0, len(x), max(1, stride)))
    n_train, n_val = split_sizes(n_strided, val_fraction)
    if n_val == 0:
        return None
    first = n_train * max(1, stride)
    xv, tv = x[first:], target[first:]
    ev = None if extra is None else extra[first:]

    def score(net: nn.Module) -> float:
        device = str(next(net.parameters()).device)
        out = predict_network(net, xv, extra=ev, device=device)
        drift = np.cumsum(out - tv, axis=0)
        return float(np.mean(drift**2))

    return score


def debias_head(
    net: nn.Module, x: np.ndarray, target: np.ndarray, extra: np.ndarray | None, device: str
) -> np.ndarray:
    """Re-fit the output bias of a change-predicting network in closed form on its training
    samples: add the mean ``target - prediction`` (scaled units) to ``net.head.bias``.

    A free run sums the predicted changes, so a constant error ``c`` in them grows into a
    drift of ``c`` per sample; the stochastic optimiser leaves such a ``c`` (it moves the
    bias by about its learning rate every step). After this step the summed changes have no
    mean drift over the training samples. Returns the shift (scaled units).
    """
    out = predict_network(net, x, extra=extra, device=device)
    shift = np.mean(np.asarray(target, np.float64) - out, axis=0)
    head = net.head
    with torch.no_grad():
        head.bias += torch.as_tensor(shift, dtype=head.bias.dtype, device=head.bias.device)
    return shift


def accumulate(level0: np.ndarray, steps: np.ndarray, start: int) -> np.ndarray:
    """``level0 + cumsum(steps[start:])`` at rows ``start ..`` (earlier rows NaN): a level
    rebuilt from per-sample changes, anchored at ``level0`` (the level at row ``start - 1``)."""
    out = np.full(steps.shape, np.nan)
    out[start:] = level0 + np.cumsum(steps[start:], axis=0)
    return out


__all__ = [
    "TASKS",
    "accumulate",
    "blank_after_init",
    "check_task_params",
    "debias_head",
    "drift_validator",
    "fit_narx",
    "increments",
    "init_rows",
    "input_matrix",
    "input_names",
    "is_simulation",
    "output_names",
    "run_narx",
]
