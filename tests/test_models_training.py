"""The shared training loop: determinism, early stopping, best weights, progress, profiles."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from drafttwin.errors import ConfigError
from drafttwin.models import MechanisticModel, Training, make_model, train_network
from drafttwin.models.estimators.networks import RecurrentRegressor, ResidualNet
from drafttwin.models.training import FitProgress
from drafttwin.models.training.loop import _mean_loss, split_sizes

from ._synthetic import hyper_for, make_series, mechanistic


@pytest.fixture(scope="module")
def series():
    return make_series(260, seed=4)[0]


def test_training_settings_are_checked_on_construction() -> None:
    for bad in ({"epochs": 0}, {"lr": float("nan")}, {"val_fraction": 1.0}, {"stride": 0},
                {"patience": 0}, {"clip_norm": -1.0}, {"device": "tpu-9"}, {"batch_size": True},
                {"schedule": "linear"}):  # fmt: skip
        name = next(iter(bad))
        with pytest.raises(ConfigError, match=f"training setting {name}="):
            Training(**bad)
    assert Training(epochs=3).replace(lr=0.1) == Training(epochs=3, lr=0.1)


def _toy(n: int = 101, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    x = rng.random((n, 6, 4)).astype(np.float32)
    y = (x[:, -1] * 0.5 + 0.1).astype(np.float32)
    return x, y


@pytest.mark.parametrize("name", ["gru", "md-s-l+d"])
def test_same_seed_same_predictions(name: str, series) -> None:
    mech = MechanisticModel(mechanistic)
    p1 = make_model(name, **hyper_for(name, seed=5)).fit(series, mech).predict_values(series, mech)
    p2 = make_model(name, **hyper_for(name, seed=5)).fit(series, mech).predict_values(series, mech)
    p3 = make_model(name, **hyper_for(name, seed=6)).fit(series, mech).predict_values(series, mech)
    np.testing.assert_array_equal(p1, p2)
    assert not np.allclose(p1, p3, equal_nan=True)


def test_fit_leaves_global_rng_and_threads_alone(series) -> None:
    torch.manual_seed(123)
    expected = torch.rand(1)
    torch.manual_seed(123)
    threads = torch.get_num_threads()
    make_model("gru", **hyper_for("gru")).fit(series)
    assert torch.equal(torch.rand(1), expected)
    assert torch.get_num_threads() == threads


def test_best_weights_are_restored() -> None:
    x, y = _toy()
    torch.manual_seed(0)
    net = RecurrentRegressor(4, 4, hidden=8, layers=1, skip=False)
    cfg = Training(epochs=6, batch_size=16, lr=0.05, patience=None, device="cpu")
    hist = train_network(net, x, y, cfg)
    n_train, n_val = split_sizes(len(x), cfg.val_fraction)
    assert (hist.n_train, hist.n_val) == (n_train, n_val) == (81, 20)
    assert len(hist.train_loss) == len(hist.val_loss) == 6
    final = _mean_loss(net, torch.from_numpy(x[n_train:]), torch.from_numpy(y[n_train:]), None)
    assert final == pytest.approx(min(hist.val_loss), rel=1e-6)
    assert hist.best_epoch == int(np.argmin(hist.val_loss))
    assert hist.samples_per_s > 0


def test_early_stopping_with_patience() -> None:
    x, y = _toy()
    torch.manual_seed(0)
    net = RecurrentRegressor(4, 4, hidden=4, layers=1)
    cfg = Training(epochs=20, batch_size=32, lr=0.01, patience=2, device="cpu")
    # a criterion that never improves after the first epoch: stop after `patience` more
    hist = train_network(net, x, y, cfg, validate=lambda net: 1.0)
    assert hist.stopped_early
    assert len(hist.train_loss) == 3


def test_no_validation_part_and_batch_of_one() -> None:
    """n_train % batch_size == 1 leaves a last batch of one sample; SKNet must cope."""
    rng = np.random.default_rng(1)
    x = rng.random((33, 7, 8)).astype(np.float32)
    y = rng.random((33, 4)).astype(np.float32)
    torch.manual_seed(0)
    net = ResidualNet(8, 4, sk_channels=6, hidden=4, layers=1)
    hist = train_network(net, x, y, Training(epochs=2, batch_size=8, val_fraction=0.0))
    assert hist.n_val == 0 and hist.val_loss == []
    assert len(hist.train_loss) == 2


def test_one_progress_bar_per_fit(series, capsys: pytest.CaptureFixture[str]) -> None:
    make_model("gru", **hyper_for("gru", quiet=False)).fit(series)
    err = capsys.readouterr().err
    assert "fit gru" in err
    make_model("gru", **hyper_for("gru", quiet=True)).fit(series)
    assert capsys.readouterr().err == ""


def test_progress_stages_reuse_one_bar() -> None:
    with FitProgress("fit x", quiet=True) as progress:
        progress.stage("a", 3)
        progress.epoch(1.0, None)
        progress.stage("b", 5)
        progress.epoch(1.0, 0.5)
        progress.finish()
        assert len(progress._progress.tasks) == 1


def test_history_is_kept(series) -> None:
    model = make_model("md-l", **hyper_for("md-l", epochs=3, patience=None))
    model.fit(series, MechanisticModel(mechanistic))
    assert len(model.history_.train_loss) == 3
    assert len(model.data_model_.history_.train_loss) == 3


def test_networks_train_on_one_thread_unless_drafttwin_threads_says_otherwise(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Spin-waiting OpenMP threads made a shared machine's fit 6x dearer in CPU time: the
    default is one thread; DRAFTTWIN_THREADS asks for more and is checked."""
    import torch

    from drafttwin.errors import ConfigError
    from drafttwin.models.training.compute import cpu_threads, training_threads

    monkeypatch.delenv("DRAFTTWIN_THREADS", raising=False)
    before = torch.get_num_threads()
    with cpu_threads(torch.device("cpu")):
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == before
    monkeypatch.setenv("DRAFTTWIN_THREADS", "3")
    assert training_threads() == 3
    for bad in ("0", "two", "-1", "1e3"):
        monkeypatch.setenv("DRAFTTWIN_THREADS", bad)
        with pytest.raises(ConfigError, match="DRAFTTWIN_THREADS"):
            training_threads()


def test_cosine_schedule_lowers_the_rate_along_half_a_cosine(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Epoch e trains with lr (1 + cos(pi e / epochs)) / 2: the full rate first, half of it
    half-way; a constant schedule keeps lr; the loop sets the optimiser's rate each epoch."""
    from drafttwin.models.training import loop as tr

    cfg = Training(epochs=4, lr=0.02, schedule="cosine")
    rates = [tr.epoch_lr(cfg, e) for e in range(4)]
    assert rates == pytest.approx([0.02, 0.02 * (1 + 2**-0.5) / 2, 0.01, 0.02 * (1 - 2**-0.5) / 2])
    assert [tr.epoch_lr(cfg.replace(schedule="constant"), e) for e in range(4)] == [0.02] * 4
    seen: list[float] = []
    train_epoch = tr._train_epoch

    def spy(net, opt, parts, config, gen):  # type: ignore[no-untyped-def]
        seen.append(opt.lr)
        return train_epoch(net, opt, parts, config, gen)

    monkeypatch.setattr(tr, "_train_epoch", spy)
    x, y = _toy()
    torch.manual_seed(0)
    train_network(RecurrentRegressor(4, 4, hidden=4, layers=1), x, y,
                  cfg.replace(patience=None, device="cpu"))  # fmt: skip
    assert seen == pytest.approx(rates)


@pytest.mark.parametrize("schedule", ["constant", "cosine"])
def test_cpu_adam_is_torch_adam_bit_for_bit(monkeypatch: pytest.MonkeyPatch, schedule: str) -> None:
    """The CPU training loop's own Adam (no torch.optim: its import of torch._dynamo cost a
    CPU-second per fit) gives exactly torch.optim.Adam's losses and weights, with the rate
    held or lowered each epoch."""
    from drafttwin.models.training import loop as tr

    own = tr.make_adam
    assert isinstance(own([torch.zeros(1, requires_grad=True)], 0.1, torch.device("cpu")),
                      tr.CpuAdam)  # fmt: skip

    x, y = _toy()
    cfg = Training(epochs=3, batch_size=16, lr=0.01, patience=None, device="cpu",
                   schedule=schedule)  # fmt: skip
    results = []
    for adam in (own, lambda p, lr, dev: torch.optim.Adam(p, lr=lr)):
        monkeypatch.setattr(tr, "make_adam", adam)
        torch.manual_seed(0)
        net = ResidualNet(4, 4, use_sknet=True, use_lstm=True, sk_channels=6, hidden=8, layers=2)
        hist = train_network(net, x, y, cfg, seed=1)
        results.append((hist.train_loss, hist.val_loss, net.state_dict()))
    (loss_a, val_a, sd_a), (loss_b, val_b, sd_b) = results
    assert loss_a == loss_b and val_a == val_b
    assert all(torch.equal(sd_a[k], sd_b[k]) for k in sd_a)


@pytest.mark.parametrize("max_norm", [1e-3, 1e3, 0.0])  # clipped, within the norm, to zero
def test_clip_gradients_is_torch_clip_grad_norm_bit_for_bit(max_norm: float) -> None:
    """The CPU loop's own gradient clipping (no grouping by device per step, no multiply by 1)
    leaves exactly the gradients ``nn.utils.clip_grad_norm_`` leaves."""
    from drafttwin.models.training.loop import clip_gradients

    x, y = _toy()
    grads = []
    for clip in (clip_gradients, torch.nn.utils.clip_grad_norm_):
        torch.manual_seed(0)
        net = ResidualNet(4, 4, use_sknet=True, use_lstm=True, sk_channels=6, hidden=8, layers=2)
        loss = torch.nn.functional.mse_loss(net(torch.from_numpy(x)), torch.from_numpy(y))
        loss.backward()  # type: ignore[no-untyped-call]
        clip(net, max_norm) if clip is clip_gradients else clip(net.parameters(), max_norm)
        grads.append([p.grad.clone() for p in net.parameters() if p.grad is not None])
    ours, torchs = grads
    assert len(ours) == len(torchs) > 0
    assert all(torch.equal(a, b) for a, b in zip(ours, torchs, strict=True))
    if max_norm == 1e-3:  # it did clip
        assert float(torch.linalg.vector_norm(torch.cat([g.flatten() for g in ours]))) < 2e-3


def test_predictions_in_cpu_chunks_equal_one_forward_pass() -> None:
    """Predicting more windows than one CPU chunk holds gives the outputs of one pass over
    all of them, bit for bit."""
    from drafttwin.models.training import loop as tr

    rng = np.random.default_rng(1)
    x = rng.random((tr.CPU_FORWARD_CHUNK * 2 + 37, 6, 4)).astype(np.float32)
    torch.manual_seed(0)
    net = ResidualNet(4, 4, use_sknet=True, use_lstm=True, sk_channels=6, hidden=8, layers=2)
    net.eval()
    with torch.no_grad():
        whole = tr._forward(net, torch.from_numpy(x), None).numpy().astype(np.float64)
    np.testing.assert_array_equal(tr.predict_network(net, x, device="cpu"), whole)
