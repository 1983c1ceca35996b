"""PyTorch networks: GRU/LSTM regressors, the 1-D selective-kernel block and the residual nets.

All networks take ``x`` of shape ``(batch, time, features)`` (oldest step first) in scaled
units and return ``(batch, outputs)`` in the same scaled units. None of them uses batch
statistics (no BatchNorm), so training and inference work with a batch of one.
"""

from __future__ import annotations

import torch
from torch import nn

from drafttwin.models.training.rng import SeededDropout


class SKConv1d(nn.Module):
    """Selective-kernel convolution over time (Li et al., CVPR 2019), adapted to 1-D.

    * **Stem**: a 1x1 convolution lifts ``in_channels`` to ``channels`` (a multiple of
      ``groups``) when they differ, e.g. 8 residual channels to 24.
    * **Split**: one branch per dilation; each is a grouped convolution (``groups`` groups,
      kernel ``kernel_size``, "same" padding, no bias) then GroupNorm and ReLU. With the default
      dilations (1, 2) the branches see 3 and 5 samples, as the official SKNet's 3x3 and
      dilated "5x5" branches.
    * **Fuse**: ``U = sum of branches``; ``s = mean of U over time``;
      ``z = ReLU(LayerNorm(W s))`` with ``W`` of size ``d x C`` and ``d = max(C // reduction,
      min_dim)``.
    * **Select**: one linear map to ``M*C`` logits, softmax over the ``M`` branches per channel,
      ``V = sum_m a_m * U_m``. With ``shortcut`` the stem output is added (SK unit).

    GroupNorm/LayerNorm replace the paper's BatchNorm so a batch of one is safe.
    """

    def __init__(
        self,
        in_channels: int,
        channels: int = 24,
        *,
        groups: int = 3,
        kernel_size: int = 3,
        dilations: tuple[int, ...] = (1, 2),
        reduction: int = 16,
        min_dim: int = 32,
        shortcut: bool = True,
    ) -> None:
        super().__init__()
        if channels % groups != 0:
            raise ValueError(f"channels ({channels}) must be a multiple of groups ({groups})")
        if kernel_size % 2 != 1 or len(dilations) < 2:
            raise ValueError("SKConv1d needs an odd kernel size and at least two branches")
        self.channels = channels
        self.n_branches = len(dilations)
        self.stem: nn.Module = (
            nn.Conv1d(in_channels, channels, 1, bias=False)
            if in_channels != channels
            else nn.Identity()
        )
        self.branches = nn.ModuleList(
            nn.Sequential(
                nn.Conv1d(
                    channels,
                    channels,
                    kernel_size,
                    padding=dil * (kernel_size - 1) // 2,
                    dilation=dil,
                    groups=groups,
                    bias=False,
                ),
                nn.GroupNorm(groups, channels),
                nn.ReLU(inplace=True),
            )
            for dil in dilations
        )
        d = max(channels // reduction, min_dim)
        self.fuse = nn.Sequential(nn.Linear(channels, d, bias=False), nn.LayerNorm(d), nn.ReLU())
        self.select = nn.Linear(d, self.n_branches * channels, bias=False)
        self.shortcut = shortcut

    def forward(
        self, x: torch.Tensor, return_attention: bool = False
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """``x``: ``(batch, in_channels, time)`` -> ``(batch, channels, time)``.

        With ``return_attention`` also returns the branch weights ``(batch, branches,
        channels)``, which sum to 1 over the branch axis.
        """
        base = self.stem(x)
        parts = torch.stack([branch(base) for branch in self.branches], dim=1)  # (B, M, C, T)
        s = parts.sum(dim=1).mean(dim=-1)  # (B, C)
        logits = self.select(self.fuse(s)).view(-1, self.n_branches, self.channels)
        attention = torch.softmax(logits, dim=1)
        v = (parts * attention.unsqueeze(-1)).sum(dim=1)
        if self.shortcut:
            v = v + base
        return (v, attention) if return_attention else v


def recurrent_stack(cell: str, n_in: int, hidden: int, layers: int, dropout: float) -> nn.Module:
    """A batch-first GRU or LSTM (``cell``) of ``layers`` layers; ``dropout`` acts between
    layers only, so a single layer has none."""
    rnn_cls = {"gru": nn.GRU, "lstm": nn.LSTM}[cell]
    rnn: nn.Module = rnn_cls(n_in, hidden, num_layers=layers, batch_first=True,
                             dropout=dropout if layers > 1 else 0.0)  # fmt: skip
    return rnn


class RecurrentRegressor(nn.Module):
    """GRU or LSTM over a window, last hidden state -> dropout -> linear head.

    With ``skip`` the head predicts a change added to the last input step's first
    ``n_outputs`` features (inputs and outputs share a scaler), so an untrained head starts as
    persistence.
    """

    def __init__(
        self,
        n_features: int,
        n_outputs: int,
        *,
        cell: str = "gru",
        hidden: int = 64,
        layers: int = 2,
        dropout: float = 0.2,
        skip: bool = True,
    ) -> None:
        super().__init__()
        self.rnn = recurrent_stack(cell, n_features, hidden, layers, dropout)
        self.drop = SeededDropout(dropout)
        self.head = nn.Linear(hidden, n_outputs)
        self.n_outputs = n_outputs
        self.skip = skip

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out, _ = self.rnn(x)
        y: torch.Tensor = self.head(self.drop(out[:, -1]))
        if self.skip:
            y = y + x[:, -1, : self.n_outputs]
        return y


class ResidualNet(nn.Module):
    """The residual model of the hybrids: optional SKNet, optional LSTM, linear head.

    * md-s-l: residual channels -> :class:`SKConv1d` -> LSTM -> last step -> head.
    * md-l: residual channels -> LSTM -> last step -> head (no SKNet).
    * md-s: residual channels -> :class:`SKConv1d` -> [mean over time, last step] -> head.

    ``extra`` (batch, n_extra) features, e.g. the current disagreement of the data-driven and
    mechanistic predictions, are concatenated in front of the head. With ``skip`` the first
    ``n_outputs`` input channels' last step is added to the output (residual persistence).
    """

    def __init__(
        self,
        n_channels: int,
        n_outputs: int = 4,
        *,
        n_extra: int = 0,
        use_sknet: bool = True,
        use_lstm: bool = True,
        sk_channels: int = 24,
        hidden: int = 64,
        layers: int = 2,
        dropout: float = 0.2,
        skip: bool = True,
    ) -> None:
        if not (use_sknet or use_lstm):
            raise ValueError("ResidualNet needs SKNet, LSTM or both")
        super().__init__()
        self.sknet = SKConv1d(n_channels, sk_channels) if use_sknet else None
        width = sk_channels if use_sknet else n_channels
        self.lstm = recurrent_stack("lstm", width, hidden, layers, dropout) if use_lstm else None
        feat = hidden if use_lstm else 2 * width
        self.drop = SeededDropout(dropout)
        self.head = nn.Linear(feat + n_extra, n_outputs)
        self.n_outputs = n_outputs
        self.n_extra = n_extra
        self.skip = skip

    def forward(self, x: torch.Tensor, extra: torch.Tensor | None = None) -> torch.Tensor:
        h = x
        if self.sknet is not None:
            h = self.sknet(h.transpose(1, 2)).transpose(1, 2)  # (B, T, C)
        if self.lstm is not None:
            out, _ = self.lstm(h)
            feat = out[:, -1]
        else:
            feat = torch.cat([h.mean(dim=1), h[:, -1]], dim=1)
        feat = self.drop(feat)
        if self.n_extra:
            if extra is None:
                raise ValueError("this ResidualNet expects extra inputs")
            feat = torch.cat([feat, extra], dim=1)
        y: torch.Tensor = self.head(feat)
        if self.skip:
            y = y + x[:, -1, : self.n_outputs]
        return y
