"""A training's own random numbers, so that nets can train side by side in threads.

PyTorch's dropout draws its masks from the process's one global generator; two nets training
at once in two threads would take each other's draws, and their numbers would depend on
timing. :class:`SeededDropout` draws from a generator the training loop hands it instead
(:func:`own_generator`), seeded as the loop seeds the global one: a net whose only random
draws in training are such masks gets the same masks, bit for bit, whether it trains alone or
beside another. A net that draws from the global generator anywhere else (a recurrent stack's
dropout between layers, a plain :class:`torch.nn.Dropout`) keeps drawing from it
(:func:`draws_global_rng`) and is trained alone.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch
from torch import nn


class SeededDropout(nn.Dropout):
    """:class:`torch.nn.Dropout` whose mask comes from ``generator`` while one is set (the
    training loop sets it); without one, the global generator's, as ``nn.Dropout``'s.

    The mask is drawn as PyTorch's own CPU dropout draws it (``bernoulli_(1 - p)``, divided
    by ``1 - p``, multiplied in), so from a generator seeded like the global one the numbers
    are the same. No parameters: a model file's state is unchanged."""

    def __init__(self, p: float = 0.5) -> None:
        super().__init__(p)
        self.generator: torch.Generator | None = None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        g = self.generator
        if g is None or not self.training or not 0.0 < self.p < 1.0 or x.numel() == 0:
            out: torch.Tensor = super().forward(x)
            return out
        noise = torch.empty_like(x).bernoulli_(1.0 - self.p, generator=g)
        noise.div_(1.0 - self.p)
        return x * noise


def draws_global_rng(net: nn.Module) -> bool:
    """Whether training ``net`` draws from PyTorch's global generator: a dropout other than
    :class:`SeededDropout`, or a recurrent stack with dropout between its layers."""
    for module in net.modules():
        if isinstance(module, nn.RNNBase) and module.dropout > 0 and module.num_layers > 1:
            return True
        if (isinstance(module, nn.modules.dropout._DropoutNd)
                and not isinstance(module, SeededDropout) and module.p > 0):  # fmt: skip
            return True
    return False


@contextlib.contextmanager
def own_generator(net: nn.Module, seed: int) -> Iterator[None]:
    """While training ``net`` with ``seed``: one generator, seeded with ``seed``, shared by
    all of its :class:`SeededDropout` layers (they draw in forward order, as from the global
    generator) unless the net draws from the global generator elsewhere
    (:func:`draws_global_rng`; then they draw from it too, as they always did). Unset
    afterwards."""
    layers = [m for m in net.modules() if isinstance(m, SeededDropout)]
    if not layers or draws_global_rng(net):
        yield
        return
    generator = torch.Generator().manual_seed(seed)
    for layer in layers:
        layer.generator = generator
    try:
        yield
    finally:
        for layer in layers:
            layer.generator = None
