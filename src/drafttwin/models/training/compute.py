"""Where and how the networks compute: the device, the CPU thread policy and deterministic
algorithms (the context every training and prediction runs in)."""

from __future__ import annotations

import contextlib
import re
import sys
import threading
from collections.abc import Iterator
from typing import Any

import torch
from torch import nn

from drafttwin.errors import ConfigError

THREADS_ENV = "DRAFTTWIN_THREADS"
"""Environment variable: intra-op CPU threads for training and predicting the networks."""

DEFAULT_THREADS = 1
"""One thread unless :data:`THREADS_ENV` asks for more. The nets are small (a batch step takes
a few ms): a second OpenMP thread gained little on an idle 2-core machine, and its
spin-waiting turned a shared machine's fit from 44 to 258 CPU-seconds
(``fit --model parallel --data default`` beside other work; benchmarks/bench_fit.py)."""


def training_threads() -> int:
    """Intra-op threads for the networks: ``DRAFTTWIN_THREADS`` (an integer from 1 to 256) or
    :data:`DEFAULT_THREADS`."""
    import os

    text = os.environ.get(THREADS_ENV, "").strip()
    if not text:
        return DEFAULT_THREADS
    if not text.isdigit() or not 1 <= int(text) <= 256:
        raise ConfigError(f"{THREADS_ENV}={text!r} is not a thread count",
                          where=THREADS_ENV, fix="set it to an integer from 1 to 256, or unset it")  # fmt: skip
    return int(text)


def _valid_device(v: Any) -> bool:
    """``auto``, ``cpu``, ``cuda``, ``cuda:N`` or ``mps`` (whether this machine has it is
    checked where the model runs; a model file falls back to the CPU)."""
    return isinstance(v, str) and re.fullmatch(r"auto|cpu|mps|cuda(:\d{1,3})?", v) is not None


def device_available(name: str) -> bool:
    """Whether this machine has the device ``name`` (``auto`` and ``cpu`` always)."""
    if name in ("auto", "cpu"):
        return True
    device = torch.device(name)
    if device.type == "cuda":
        return torch.cuda.is_available() and (device.index or 0) < torch.cuda.device_count()
    if device.type == "mps":
        return bool(torch.backends.mps.is_available())
    return False


def resolve_device(name: str) -> torch.device:
    """``"auto"`` -> CUDA when available, else CPU; otherwise ``torch.device(name)``, refused
    in one line where this machine lacks it (PyTorch had raised "Torch not compiled with
    CUDA enabled" from deep inside the first training step)."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if not device_available(name):
        raise ConfigError("training device {device} is not on this machine (its PyTorch has "
                          "no such device)", terms={"device": name},
                          fix="{device:name} auto (a GPU where there is one) or cpu")  # fmt: skip
    return torch.device(name)


@contextlib.contextmanager
def cpu_threads(device: torch.device, limit: int | None = None) -> Iterator[None]:
    """Set intra-op CPU threads to ``limit`` (default :func:`training_threads`), restored
    afterwards.

    Step-by-step loops over a few windows pass ``limit=1``: each call is too small to share
    out, and waking a second thread per step cost 4-7x its time on a busy 2-core machine.
    """
    threads = torch.get_num_threads()
    if device.type == "cpu":
        torch.set_num_threads(training_threads() if limit is None else limit)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def _set_deterministic(mode: bool, *, warn_only: bool) -> None:
    """``torch.use_deterministic_algorithms`` without its import of ``torch._inductor`` (about
    a CPU-second per process; drafttwin compiles nothing): the compiler's own flag is set as
    well once something else has imported it."""

    inductor: Any = sys.modules.get("torch._inductor.config")
    if inductor is not None:
        inductor.deterministic = mode
    torch._C._set_deterministic_algorithms(mode, warn_only=warn_only)


_context_lock = threading.Lock()
_context_depth = 0
_context_saved: tuple[bool, bool, bool] = (False, False, True)


@contextlib.contextmanager
def compute_context(device: torch.device) -> Iterator[None]:
    """Deterministic algorithms and a capped CPU thread count, restored afterwards.

    Used around training; toggling determinism costs about a millisecond, so inference (which
    is deterministic on CPU anyway) uses :func:`cpu_threads` only. Counted: nets training side
    by side in threads enter it each, and the flags are restored when the last one leaves
    (the first to leave would otherwise switch them off under the others).
    """
    global _context_depth, _context_saved
    with _context_lock:
        if _context_depth == 0:
            # torch sets this module attribute at import time; its stubs do not declare it
            fill = torch.utils.deterministic.fill_uninitialized_memory  # type: ignore[attr-defined]
            _context_saved = (torch.are_deterministic_algorithms_enabled(),
                              torch.is_deterministic_algorithms_warn_only_enabled(), fill)  # fmt: skip
            _set_deterministic(True, warn_only=device.type != "cpu")
            # filling every new tensor with NaN only helps debugging and costs ~15 % on conv nets
            torch.utils.deterministic.fill_uninitialized_memory = False  # type: ignore[attr-defined]
        _context_depth += 1
    try:
        with cpu_threads(device):
            yield
    finally:
        with _context_lock:
            _context_depth -= 1
            if _context_depth == 0:
                det, warn, fill = _context_saved
                _set_deterministic(det, warn_only=warn)
                torch.utils.deterministic.fill_uninitialized_memory = fill  # type: ignore[attr-defined]


def place(net: nn.Module, device: torch.device) -> None:
    """Put ``net`` on ``device`` in eval mode, touching it only if needed (cheap per call)."""
    param = next(net.parameters(), None)
    if param is not None and param.device != device:
        net.to(device)
    if net.training:
        net.eval()
