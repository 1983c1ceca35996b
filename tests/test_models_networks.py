"""Network building blocks: SKNet (split/fuse/select), recurrent regressors, residual nets."""

from __future__ import annotations

import pytest
import torch

from drafttwin.models.estimators.networks import RecurrentRegressor, ResidualNet, SKConv1d


def test_sknet_shapes_and_attention_sum_to_one() -> None:
    torch.manual_seed(0)
    sk = SKConv1d(8, 24)
    x = torch.randn(5, 8, 20)
    v, att = sk(x, return_attention=True)
    assert v.shape == (5, 24, 20)
    assert att.shape == (5, 2, 24)
    torch.testing.assert_close(att.sum(dim=1), torch.ones(5, 24))
    assert (att > 0).all()


def test_sknet_attention_depends_on_input() -> None:
    """Select is input-adaptive: different inputs give different branch weights."""
    torch.manual_seed(0)
    sk = SKConv1d(6, 12, min_dim=4)
    _, a1 = sk(torch.randn(1, 6, 16), return_attention=True)
    _, a2 = sk(5 * torch.randn(1, 6, 16) + 3, return_attention=True)
    assert not torch.allclose(a1, a2)


def test_sknet_batch_of_one_in_training_mode() -> None:
    torch.manual_seed(0)
    sk = SKConv1d(8, 24).train()
    out = sk(torch.randn(1, 8, 10))
    out.sum().backward()
    assert out.shape == (1, 24, 10)
    assert all(p.grad is not None for p in sk.parameters())


@pytest.mark.parametrize("in_channels", [1, 4, 8, 9])
def test_sknet_lifts_any_channel_count(in_channels: int) -> None:
    sk = SKConv1d(in_channels, 12)
    assert sk(torch.randn(2, in_channels, 7)).shape == (2, 12, 7)
    # the stem is a 1x1 convolution unless the input already has the block's width
    assert isinstance(sk.stem, torch.nn.Conv1d) == (in_channels != 12)


def test_sknet_grouped_convolutions_and_branches() -> None:
    sk = SKConv1d(8, 24)
    convs = [b[0] for b in sk.branches]
    assert [c.groups for c in convs] == [3, 3]
    assert [c.dilation[0] for c in convs] == [1, 2]  # receptive fields 3 and 5
    # d = max(C / r, L) = max(24 // 16, 32) = 32
    assert sk.fuse[0].out_features == 32
    assert sk.select.out_features == 2 * 24


def test_sknet_refuses_width_not_multiple_of_groups() -> None:
    with pytest.raises(ValueError, match="multiple of groups"):
        SKConv1d(8, 10)


@pytest.mark.parametrize("cell", ["gru", "lstm"])
def test_recurrent_regressor_shapes(cell: str) -> None:
    net = RecurrentRegressor(4, 4, cell=cell, hidden=8, layers=2)
    assert net(torch.randn(3, 11, 4)).shape == (3, 4)
    assert net(torch.randn(1, 11, 4)).shape == (1, 4)


def test_recurrent_skip_starts_near_persistence() -> None:
    """With skip, the output is the last input step plus a learned change."""
    net = RecurrentRegressor(4, 4, hidden=8, layers=1, skip=True)
    torch.nn.init.zeros_(net.head.weight)
    torch.nn.init.zeros_(net.head.bias)
    x = torch.randn(2, 6, 4)
    torch.testing.assert_close(net.eval()(x), x[:, -1])


@pytest.mark.parametrize(
    ("sknet", "lstm"), [(True, True), (False, True), (True, False)], ids=["md-s-l", "md-l", "md-s"]
)
@pytest.mark.parametrize("n_extra", [0, 4])
def test_residual_net_variants(sknet: bool, lstm: bool, n_extra: int) -> None:
    net = ResidualNet(8, 4, n_extra=n_extra, use_sknet=sknet, use_lstm=lstm, sk_channels=12)
    extra = torch.randn(2, n_extra) if n_extra else None
    assert net(torch.randn(2, 9, 8), extra).shape == (2, 4)
    assert (net.sknet is not None) == sknet
    assert (net.lstm is not None) == lstm


def test_residual_net_needs_a_block() -> None:
    with pytest.raises(ValueError):
        ResidualNet(8, use_sknet=False, use_lstm=False)
