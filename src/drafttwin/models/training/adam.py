"""Adam on the CPU without ``torch.optim``: the same numbers, less start-up and per-step cost.

:class:`CpuAdam` computes exactly what ``torch.optim.Adam(params, lr=lr)`` computes on the CPU
(its single-tensor path, which torch takes there: no weight decay, amsgrad, maximize, foreach
or fused; a step count per parameter, its state created at its first gradient), operation for
operation, so the weights come out bit-identical (checked by the tests). What it leaves out:
creating a ``torch.optim.Optimizer`` imports ``torch._dynamo`` and ``torch._inductor`` (about
a CPU-second at the start of every fit; drafttwin compiles nothing), and each of its steps
passes hooks, profiler records and a per-parameter ``.item()``. Other devices keep
``torch.optim.Adam`` (see :func:`make_adam`), whose default there (foreach) differs.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import cast

import torch


class CpuAdam:
    """``torch.optim.Adam(params, lr=lr)`` for CPU tensors (``betas`` 0.9, 0.999; ``eps`` 1e-8).

    Only what the training loop calls: :meth:`zero_grad` (gradients set to ``None``) and
    :meth:`step`.
    """

    def __init__(self, params: Iterable[torch.Tensor], lr: float) -> None:
        self.params = list(params)
        if not self.params:
            raise ValueError("optimizer got an empty parameter list")
        self.lr, self.beta1, self.beta2, self.eps = lr, 0.9, 0.999, 1e-8
        self.steps = [0] * len(self.params)
        self.exp_avg: list[torch.Tensor | None] = [None] * len(self.params)
        self.exp_avg_sq: list[torch.Tensor | None] = [None] * len(self.params)

    def zero_grad(self, set_to_none: bool = True) -> None:
        for p in self.params:
            if set_to_none:
                p.grad = None
            elif p.grad is not None:
                p.grad.zero_()

    @torch.no_grad()
    def step(self) -> None:
        live = [i for i, p in enumerate(self.params) if p.grad is not None]
        for i in live:
            if self.exp_avg[i] is None:
                self.exp_avg[i] = torch.zeros_like(self.params[i])
                self.exp_avg_sq[i] = torch.zeros_like(self.params[i])
            self.steps[i] += 1
        counts = {self.steps[i] for i in live}
        if len(counts) == 1:  # the usual case: every parameter at the same step, in one go
            self._update(live, float(counts.pop()))
        else:
            for i in live:
                self._update([i], float(self.steps[i]))

    def _update(self, idx: list[int], step: float) -> None:
        """Torch's single-tensor Adam step on the parameters ``idx`` (all at ``step``; torch
        keeps it in a float32 tensor: exact to 2**24), each operation applied to all of them
        at once (``torch._foreach_*``: on the CPU a loop of the same per-tensor kernels, so
        the same numbers, without a Python call per tensor and operation)."""
        params = [self.params[i] for i in idx]
        grads = [cast(torch.Tensor, p.grad) for p in params]
        exp_avg = [cast(torch.Tensor, self.exp_avg[i]) for i in idx]
        exp_avg_sq = [cast(torch.Tensor, self.exp_avg_sq[i]) for i in idx]
        torch._foreach_lerp_(exp_avg, grads, 1 - self.beta1)
        torch._foreach_mul_(exp_avg_sq, self.beta2)
        torch._foreach_addcmul_(exp_avg_sq, grads, grads, value=1 - self.beta2)
        bias_correction1 = 1 - self.beta1**step
        bias_correction2 = 1 - self.beta2**step
        step_size = self.lr / bias_correction1
        bias_correction2_sqrt = bias_correction2**0.5
        denom = torch._foreach_sqrt(exp_avg_sq)
        torch._foreach_div_(denom, bias_correction2_sqrt)
        torch._foreach_add_(denom, self.eps)
        torch._foreach_addcdiv_(params, exp_avg, denom, value=-step_size)


def make_adam(
    params: Iterable[torch.Tensor], lr: float, device: torch.device
) -> CpuAdam | torch.optim.Adam:
    """:class:`CpuAdam` on the CPU, ``torch.optim.Adam`` elsewhere."""
    if device.type == "cpu":
        return CpuAdam(params, lr)
    return torch.optim.Adam(params, lr=lr)
