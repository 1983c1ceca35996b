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
        beta1, beta2 = self.beta1, self.beta2
        for i, param in enumerate(self.params):
            grad = param.grad
            if grad is None:
                continue
            exp_avg, exp_avg_sq = self.exp_avg[i], self.exp_avg_sq[i]
            if exp_avg is None or exp_avg_sq is None:
                exp_avg = self.exp_avg[i] = torch.zeros_like(param)
                exp_avg_sq = self.exp_avg_sq[i] = torch.zeros_like(param)
            self.steps[i] += 1
            step = float(self.steps[i])  # torch keeps it in a float32 tensor: exact to 2**24
            exp_avg.lerp_(grad, 1 - beta1)
            exp_avg_sq.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
            bias_correction1 = 1 - beta1**step
            bias_correction2 = 1 - beta2**step
            step_size = self.lr / bias_correction1
            bias_correction2_sqrt = bias_correction2**0.5
            denom = (exp_avg_sq.sqrt() / bias_correction2_sqrt).add_(self.eps)
            param.addcdiv_(exp_avg, denom, value=-step_size)


def make_adam(
    params: Iterable[torch.Tensor], lr: float, device: torch.device
) -> CpuAdam | torch.optim.Adam:
    """:class:`CpuAdam` on the CPU, ``torch.optim.Adam`` elsewhere."""
    if device.type == "cpu":
        return CpuAdam(params, lr)
    return torch.optim.Adam(params, lr=lr)
