"""The one training loop used by every network in drafttwin.

Adam on mean-squared error in scaled units, mini-batches shuffled by a seeded
``torch.Generator``, validation on the last ``val_fraction`` of the (chronologically ordered)
training samples, early stopping with patience and restoration of the best weights, optional
gradient-norm clipping, deterministic algorithms, CPU/GPU selection, and one rich progress bar
per model fit (on stderr; silent with ``quiet``).
"""

from __future__ import annotations

import concurrent.futures as cf
import copy
import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any, TypedDict

import numpy as np
import torch
from torch import nn

from drafttwin.errors import ConfigError, DataError
from drafttwin.models.training.adam import CpuAdam, make_adam
from drafttwin.models.training.compute import (
    _valid_device,
    compute_context,
    cpu_threads,
    place,
    resolve_device,
)
from drafttwin.models.training.progress import FitProgress
from drafttwin.models.training.rng import own_generator
from drafttwin.models.training.side_by_side import check_cancelled, wait_for

SCHEDULES = ("constant", "cosine")
"""How the learning rate moves over the epochs: ``constant`` keeps ``lr``; ``cosine`` lowers it
from ``lr`` towards 0 along half a cosine over ``epochs`` (epoch ``e`` trains with
``lr * (1 + cos(pi * e / epochs)) / 2``), so the last epochs fine-tune instead of jumping."""


_TRAINING_RULES: dict[str, tuple[Callable[[Any], bool], str]] = {
    "epochs": (lambda v: _is_int(v) and v >= 1, "an integer >= 1"),
    "batch_size": (lambda v: _is_int(v) and v >= 1, "an integer >= 1"),
    "lr": (lambda v: _is_real(v) and 0 < v < math.inf, "a number > 0"),
    "patience": (lambda v: v is None or (_is_int(v) and v >= 1), "None or an integer >= 1"),
    "val_fraction": (lambda v: _is_real(v) and 0 <= v < 1, "in [0, 1)"),
    "clip_norm": (lambda v: v is None or (_is_real(v) and 0 < v < math.inf), "None or > 0"),
    "stride": (lambda v: _is_int(v) and v >= 1, "an integer >= 1"),
    "schedule": (lambda v: v in SCHEDULES, '"constant" or "cosine"'),
    "device": (lambda v: _valid_device(v), '"auto", "cpu", "cuda", "cuda:N" or "mps"'),
}


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v: Any) -> bool:  # NaN allowed: an epoch's loss may be undefined
    return isinstance(v, int | float) and not isinstance(v, bool)


def _is_real(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


@dataclass(frozen=True)
class Training:
    """How a network is trained (checked on construction; see :mod:`drafttwin.models.profiles`
    for the named presets). The seed is the estimator's, not part of these settings.

    Attributes:
        epochs: maximum passes over the training samples.
        batch_size: samples per Adam step.
        lr: Adam learning rate.
        patience: epochs without validation improvement before stopping (``None``: never).
        val_fraction: share of the training samples, taken from the end, that validates.
        clip_norm: gradient-norm clipping threshold (``None``: no clipping).
        stride: use every ``stride``-th training sample (chronological order kept); 1 = all.
        schedule: the learning rate over the epochs, ``"constant"`` or ``"cosine"``
            (:data:`SCHEDULES`).
        device: ``"auto"`` (CUDA when available), ``"cpu"``, ``"cuda"`` or ``"cuda:N"``.
    """

    epochs: int = 30
    batch_size: int = 64
    lr: float = 1e-3
    patience: int | None = 5
    val_fraction: float = 0.2
    clip_norm: float | None = 1.0
    stride: int = 1
    schedule: str = "constant"
    device: str = "auto"

    def __post_init__(self) -> None:
        for name, (ok, rule) in _TRAINING_RULES.items():
            value = getattr(self, name)
            if not ok(value):
                raise ConfigError(f"training setting {{{name}}} is invalid",
                                  terms={name: value}, fix=f"{{{name}:name}} must be {rule}")  # fmt: skip

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def replace(self, **changes: Any) -> Training:
        return dataclasses.replace(self, **changes)


class HistoryDict(TypedDict):
    """:class:`History` as plain data (JSON)."""

    train_loss: list[float]
    val_loss: list[float]
    best_epoch: int
    stopped_early: bool
    seconds: float
    n_train: int
    n_val: int


@dataclass
class History:
    """Loss per epoch (MSE in scaled units) and what the loop did.

    ``val_loss`` is empty when there was no validation part; ``best_epoch`` is 0-based.
    """

    train_loss: list[float] = field(default_factory=list)
    val_loss: list[float] = field(default_factory=list)
    best_epoch: int = 0
    stopped_early: bool = False
    seconds: float = 0.0
    n_train: int = 0
    n_val: int = 0

    @property
    def samples_per_s(self) -> float:
        """Training samples processed per second of wall time (validation time included)."""
        epochs = len(self.train_loss)
        return self.n_train * epochs / self.seconds if self.seconds > 0 else float("nan")

    def to_dict(self) -> HistoryDict:
        return {
            "train_loss": list(self.train_loss),
            "val_loss": list(self.val_loss),
            "best_epoch": self.best_epoch,
            "stopped_early": self.stopped_early,
            "seconds": self.seconds,
            "n_train": self.n_train,
            "n_val": self.n_val,
        }

    @classmethod
    def from_dict(cls, data: HistoryDict) -> History:
        """The inverse of :meth:`to_dict`; ``ValueError`` for a field of the wrong kind (a
        model file is untrusted input)."""
        if not isinstance(data, dict) or set(data) != set(HistoryDict.__annotations__):
            raise ValueError(
                f"a training history holds the fields {sorted(HistoryDict.__annotations__)}"
            )
        raw: dict[str, Any] = dict(data)
        for key in ("train_loss", "val_loss"):
            if not isinstance(raw[key], list) or not all(_is_number(x) for x in raw[key]):
                raise ValueError(f"history {key} is not a list of numbers")
        for key in ("best_epoch", "n_train", "n_val"):
            if not _is_int(raw[key]) or raw[key] < 0:
                raise ValueError(f"history {key} is not an integer >= 0")
        if not isinstance(raw["stopped_early"], bool) or not _is_real(raw["seconds"]):
            raise ValueError("history stopped_early or seconds is of the wrong kind")
        return cls(**data)


def _as_tensor(x: np.ndarray | None, device: torch.device) -> torch.Tensor | None:
    return None if x is None else torch.as_tensor(np.asarray(x, dtype=np.float32), device=device)


def _forward(net: nn.Module, x: torch.Tensor, extra: torch.Tensor | None) -> torch.Tensor:
    y: torch.Tensor = net(x) if extra is None else net(x, extra)
    return y


CPU_FORWARD_CHUNK = 1024
"""Windows per forward pass when predicting on the CPU: a recurrent net's forward over 1,024
windows took a fifth less time per window than over 4,096 (2-core AMD EPYC), with the
same outputs bit for bit."""


def _forward_chunks(net: nn.Module, x: torch.Tensor, extra: torch.Tensor | None) -> torch.Tensor:
    """``net`` over ``x`` in pieces of :data:`CPU_FORWARD_CHUNK` windows on the CPU."""
    step = CPU_FORWARD_CHUNK if x.device.type == "cpu" else x.shape[0]
    if x.shape[0] <= step:
        return _forward(net, x, extra)
    return torch.cat([_forward(net, x[i : i + step], None if extra is None else extra[i : i + step])
                      for i in range(0, x.shape[0], step)])  # fmt: skip


def _mean_loss(
    net: nn.Module,
    x: torch.Tensor,
    y: torch.Tensor,
    extra: torch.Tensor | None,
    chunk: int = 4096,
) -> float:
    """MSE over all samples, evaluated in eval mode, summed in chunks of ``chunk``."""
    net.eval()
    total = 0.0
    with torch.no_grad():
        for i in range(0, x.shape[0], chunk):
            e = None if extra is None else extra[i : i + chunk]
            out = _forward_chunks(net, x[i : i + chunk], e)
            total += float(nn.functional.mse_loss(out, y[i : i + chunk], reduction="sum"))
    return total / (y.shape[0] * y.shape[1])


def split_sizes(n: int, val_fraction: float) -> tuple[int, int]:
    """``(n_train, n_val)``: the last ``floor(n * val_fraction)`` samples validate (if >= 1 and
    at least one training sample remains)."""
    n_val = int(math.floor(n * val_fraction))
    if n - n_val < 1:
        n_val = 0
    return n - n_val, n_val


def train_network(
    net: nn.Module,
    x: np.ndarray,
    y: np.ndarray,
    config: Training,
    *,
    seed: int = 0,
    extra: np.ndarray | None = None,
    progress: FitProgress | None = None,
    stage: str = "training",
    validate: Callable[[nn.Module], float] | None = None,
    until: cf.Future[int] | None = None,
) -> History:
    """Train ``net`` in place on windows ``x`` (N, T, F), targets ``y`` (N, outputs) and
    optional per-sample ``extra`` (N, E), all in scaled units and chronological order.

    Returns the loss history; the network ends with the best weights (lowest validation loss,
    or training loss when there is no validation part) and in eval mode, on ``config.device``.
    Weight initialisation is the caller's job (seed before building the net). With
    ``config.stride > 1`` only every ``stride``-th sample is used (for densely sampled records
    whose neighbouring windows are nearly identical). ``validate(net) -> loss``, if given,
    replaces the MSE on the validation part as the early-stopping criterion (e.g. a free-run
    error); it runs with gradients off and the net in eval mode, whenever there is a
    validation part. ``until``: the epochs to train, known later (a judge whose length its
    final net sets), waited for first (:func:`train_ahead` trains meanwhile).
    """
    if until is not None:
        config = config.replace(epochs=wait_for(until))
    return _fit(net, x, y, config, seed, extra, progress, stage, validate)


@dataclass
class Ahead:
    """A run trained ahead of its length (:func:`train_ahead`): its history, the epochs it
    was set up for and, where a shorter run is the start of a longer one, per epoch run the
    best weights so far and their epoch (``states``; ``None``: the run is a guess at the
    whole length, right or wrong as a whole)."""

    history: History
    planned: int
    states: list[tuple[dict[str, torch.Tensor], int]] | None

    def cut(self, net: nn.Module, epochs: int) -> bool:
        """End ``net`` as a run of ``epochs`` epochs ends (its best weights among them, eval
        mode; :attr:`history` then that run's). ``False``: it cannot (a guess at another
        length, or one stopped once it was known wrong): train it again."""
        if self.states is None:
            return epochs == self.planned == len(self.history.train_loss)
        if not 1 <= epochs <= len(self.states):
            raise ValueError(f"{epochs} epochs asked of a run of {len(self.states)}")
        state, self.history.best_epoch = self.states[epochs - 1]
        net.load_state_dict(state)
        net.eval()
        del self.history.train_loss[epochs:]
        return True


def runs_ahead(config: Training) -> bool:
    """Whether a run of fewer epochs under ``config`` is the start of a longer one (a
    constant learning rate, no validation part, no patience)."""
    return config.schedule == "constant" and config.val_fraction == 0 and config.patience is None


def train_ahead(
    net: nn.Module,
    x: np.ndarray,
    y: np.ndarray,
    config: Training,
    *,
    until: cf.Future[int],
    seed: int = 0,
    extra: np.ndarray | None = None,
    progress: FitProgress | None = None,
    stage: str = "training",
) -> Ahead:
    """Train ``net`` as ``train_network(..., until=until)`` would, without waiting for
    ``until`` (at most ``config.epochs``): where a shorter run is the start of a longer one
    (:func:`runs_ahead`) it trains ahead and stops once ``until`` is known and reached;
    otherwise (a learning-rate schedule over the epochs) it bets on ``config.epochs`` and
    stops as soon as ``until`` says otherwise. :meth:`Ahead.cut` ends it bit for bit as the
    run of ``until``'s epochs, or says it lost the bet."""
    prefix = runs_ahead(config)
    ahead = Ahead(History(), config.epochs, [] if prefix else None)

    def stop(epoch: int) -> bool:
        if not until.done():
            return False
        return epoch >= until.result() if prefix else until.result() != config.epochs

    ahead.history = _fit(net, x, y, config, seed, extra, progress, stage, None, stop,
                         ahead.states)  # fmt: skip
    return ahead


def _fit(
    net: nn.Module, x: np.ndarray, y: np.ndarray, config: Training, seed: int,
    extra: np.ndarray | None, progress: FitProgress | None, stage: str,
    validate: Callable[[nn.Module], float] | None, stop: Callable[[int], bool] | None = None,
    ahead: list[tuple[dict[str, torch.Tensor], int]] | None = None,
) -> History:  # fmt: skip
    """:func:`train_network`'s work (``stop`` and ``ahead``: :func:`train_ahead`'s)."""
    if config.stride > 1:
        x, y = x[:: config.stride], y[:: config.stride]
        extra = None if extra is None else extra[:: config.stride]
    n = int(x.shape[0])
    if n < 2:
        raise DataError(
            f"only {n} usable training window(s) for {stage}",
            fix="use a longer training part ({data:name}, {train_fraction:name}), or shorten "
            "{window:name}",
            terms={"data": None, "train_fraction": None, "window": None},
        )
    device = resolve_device(config.device)
    n_train, n_val = split_sizes(n, config.val_fraction)
    history = History(n_train=n_train, n_val=n_val)
    start = time.perf_counter()
    cuda = [device.index or 0] if device.type == "cuda" else []
    with compute_context(device), torch.random.fork_rng(devices=cuda):
        torch.manual_seed(seed)
        gen = torch.Generator().manual_seed(seed)
        net.to(device)
        xt, yt, et = _as_tensor(x, device), _as_tensor(y, device), _as_tensor(extra, device)
        assert xt is not None and yt is not None
        parts = _Split(xt, yt, et, n_train)
        opt = make_adam(net.parameters(), config.lr, device)  # torch's numbers, less overhead
        if progress is not None:
            progress.stage(stage, config.epochs)
        with own_generator(net, seed):
            _run_epochs(net, opt, parts, config, gen, history, progress, validate, stop, ahead)
    history.seconds = time.perf_counter() - start
    net.eval()
    return history


@dataclass
class _Split:
    x: torch.Tensor
    y: torch.Tensor
    extra: torch.Tensor | None
    n_train: int

    def train(self, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        e = None if self.extra is None else self.extra[idx]
        return self.x[idx], self.y[idx], e

    def val(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        k = self.n_train
        e = None if self.extra is None else self.extra[k:]
        return self.x[k:], self.y[k:], e


def _run_epochs(
    net: nn.Module,
    opt: CpuAdam | torch.optim.Optimizer,
    parts: _Split,
    config: Training,
    gen: torch.Generator,
    history: History,
    progress: FitProgress | None,
    validate: Callable[[nn.Module], float] | None = None,
    stop: Callable[[int], bool] | None = None,
    ahead: list[tuple[dict[str, torch.Tensor], int]] | None = None,
) -> None:
    """Train the epochs, ending before epoch ``e`` where ``stop(e)``; with ``ahead``, keep
    each epoch's best-so-far weights and their epoch there."""
    best = math.inf
    best_state = copy.deepcopy(net.state_dict())
    stale = 0
    for epoch in range(config.epochs):
        if stop is not None and stop(epoch):
            break
        _set_lr(opt, epoch_lr(config, epoch))
        train_loss = _train_epoch(net, opt, parts, config, gen)
        history.train_loss.append(train_loss)
        val_loss = None
        if history.n_val:
            vx, vy, ve = parts.val()
            if validate is None:
                val_loss = _mean_loss(net, vx, vy, ve)
            else:
                net.eval()
                with torch.no_grad():
                    val_loss = float(validate(net))
            history.val_loss.append(val_loss)
        if progress is not None:
            progress.epoch(train_loss, val_loss)
        score = train_loss if val_loss is None else val_loss
        if score < best:
            best, stale, history.best_epoch = score, 0, epoch
            best_state = copy.deepcopy(net.state_dict())
        else:
            stale += 1
            if config.patience is not None and stale >= config.patience:
                history.stopped_early = True
                break
        if ahead is not None:
            ahead.append((best_state, history.best_epoch))
    net.load_state_dict(best_state)
    if progress is not None:
        progress.finish(history)


def epoch_lr(config: Training, epoch: int) -> float:
    """The learning rate of 0-based ``epoch`` under ``config.schedule``."""
    if config.schedule == "cosine":
        return config.lr * 0.5 * (1.0 + math.cos(math.pi * epoch / config.epochs))
    return config.lr


def _set_lr(opt: CpuAdam | torch.optim.Optimizer, lr: float) -> None:
    if isinstance(opt, CpuAdam):
        opt.lr = lr
        return
    for group in opt.param_groups:
        group["lr"] = lr


def _train_epoch(
    net: nn.Module,
    opt: CpuAdam | torch.optim.Optimizer,
    parts: _Split,
    config: Training,
    gen: torch.Generator,
) -> float:
    """One pass over the shuffled training samples; returns the mean training MSE."""
    net.train()
    perm = torch.randperm(parts.n_train, generator=gen).to(parts.x.device)
    total = torch.zeros((), device=parts.x.device)
    for i in range(0, parts.n_train, config.batch_size):
        check_cancelled()
        bx, by, be = parts.train(perm[i : i + config.batch_size])
        opt.zero_grad(set_to_none=True)
        loss = nn.functional.mse_loss(_forward(net, bx, be), by)
        loss.backward()  # type: ignore[no-untyped-call]  # torch leaves Tensor.backward unannotated
        if config.clip_norm is not None:
            clip_gradients(net, config.clip_norm)
        opt.step()
        total += loss.detach() * by.shape[0]
    return float(total) / parts.n_train


def clip_gradients(net: nn.Module, max_norm: float) -> None:
    """``nn.utils.clip_grad_norm_(net.parameters(), max_norm)``, the same numbers: on the CPU
    without its grouping by device and type per step, and without multiplying the gradients by
    a factor of exactly 1 (no change) when their norm is within ``max_norm``."""
    params = [p for p in net.parameters() if p.grad is not None]
    if not params or params[0].device.type != "cpu":
        nn.utils.clip_grad_norm_(net.parameters(), max_norm)
        return
    grads = [p.grad for p in params if p.grad is not None]
    total = torch.linalg.vector_norm(torch.stack(torch._foreach_norm(grads, 2.0)), 2.0)
    coef = torch.clamp(max_norm / (total + 1e-6), max=1.0)
    if float(coef) != 1.0:  # NaN too, as torch multiplies by it
        torch._foreach_mul_(grads, coef)


def predict_network(
    net: nn.Module,
    x: np.ndarray,
    *,
    extra: np.ndarray | None = None,
    device: str = "auto",
    chunk: int = 4096,
) -> np.ndarray:
    """Run ``net`` in eval mode on windows ``x`` (N, T, F); returns float64 (N, outputs)."""
    dev = resolve_device(device)
    place(net, dev)
    outs: list[np.ndarray] = []
    with cpu_threads(dev), torch.inference_mode():
        for i in range(0, x.shape[0], chunk):
            xt = _as_tensor(x[i : i + chunk], dev)
            et = None if extra is None else _as_tensor(extra[i : i + chunk], dev)
            assert xt is not None
            outs.append(_forward_chunks(net, xt, et).cpu().numpy().astype(np.float64))
    if not outs:
        n_out = int(getattr(net, "n_outputs", 0))
        return np.zeros((0, n_out), dtype=np.float64)
    return np.concatenate(outs, axis=0)


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
    shift: np.ndarray = np.mean(np.asarray(target, np.float64) - out, axis=0)
    head = net.head
    if not isinstance(head, nn.Linear):
        raise TypeError(f"{type(net).__name__} has no linear output layer 'head' to re-fit")
    with torch.no_grad():
        head.bias.add_(torch.as_tensor(shift, dtype=head.bias.dtype, device=head.bias.device))
    return shift
