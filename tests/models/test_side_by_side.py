"""Nets of one fit trained side by side in threads: the same numbers as one after the other
(their own dropout generators, judges trained ahead of their length and cut back), a stop
that takes a batch, and the worker count a user and a parallel run set."""

from __future__ import annotations

import concurrent.futures as cf
import json
import signal
import threading
import time

import numpy as np
import pytest
import torch
from torch import nn

from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import ConfigError, DataError
from drafttwin.execution.executor import PARALLEL_TASK_ENV, run_tasks
from drafttwin.models import MechanisticModel, make_model
from drafttwin.models.estimators.networks import ResidualNet
from drafttwin.models.training import FitProgress, Training, train_ahead, train_network
from drafttwin.models.training.compute import compute_context
from drafttwin.models.training.rng import SeededDropout, draws_global_rng
from drafttwin.models.training.side_by_side import (
    WORKERS_ENV,
    check_cancelled,
    side_by_side,
    training_workers,
)

from .._synthetic import TINY
from .._tasks import parallel_task_mark

N = 360


def _windows(seed: int = 0, n: int = 300) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, 6, 2)).astype(np.float32)
    return x, (x[:, -3:, :1].sum(axis=1) + 0.1 * rng.normal(size=(n, 1))).astype(np.float32)


def _net(layers: int = 1) -> ResidualNet:
    torch.manual_seed(4)
    return ResidualNet(2, 1, use_sknet=False, hidden=8, layers=layers, dropout=0.3)


def _weights(net: nn.Module) -> list[np.ndarray]:
    return [v.detach().numpy().copy() for v in net.state_dict().values()]


def test_seeded_dropout_draws_the_global_generators_masks_from_its_own() -> None:
    x = torch.randn(64, 12, requires_grad=True)
    torch.manual_seed(11)
    plain = nn.functional.dropout(x, 0.3, training=True)
    layer = SeededDropout(0.3)
    layer.generator = torch.Generator().manual_seed(11)
    torch.manual_seed(999)  # the global generator is not what it draws from
    seeded = layer(x)
    assert torch.equal(plain, seeded)
    assert not torch.equal(seeded, x)
    (g1,) = torch.autograd.grad(plain.sum(), x)
    (g2,) = torch.autograd.grad(seeded.sum(), x)
    assert torch.equal(g1, g2)
    assert torch.equal(layer.eval()(x), x)


def test_nets_that_draw_from_the_global_generator_are_told_apart() -> None:
    assert not draws_global_rng(_net(layers=1))  # one LSTM layer: no dropout between layers
    assert draws_global_rng(_net(layers=2))
    assert draws_global_rng(nn.Sequential(nn.Linear(2, 2), nn.Dropout(0.1)))
    assert not draws_global_rng(nn.Sequential(nn.Linear(2, 2), nn.Dropout(0.0)))


def test_a_net_trains_to_the_same_weights_whatever_the_global_generator_does() -> None:
    x, y = _windows()
    config = Training(epochs=2, batch_size=32, device="cpu", patience=None)
    a, b = _net(), _net()
    train_network(a, x, y, config, seed=5)
    torch.manual_seed(123)
    _ = torch.rand(1000)  # another thread drawing meanwhile moves the global generator
    train_network(b, x, y, config, seed=5)
    assert all(np.array_equal(p, q) for p, q in zip(_weights(a), _weights(b), strict=True))


@pytest.mark.parametrize("schedule", ["constant", "cosine"])
def test_a_run_trained_ahead_and_cut_is_the_run_of_that_length(schedule: str) -> None:
    x, y = _windows(1)
    config = Training(epochs=5, batch_size=32, device="cpu", patience=None, val_fraction=0.0,
                      schedule=schedule)  # fmt: skip
    for wanted in (3, 5):
        alone = _net()
        expected = train_network(alone, x, y, config.replace(epochs=wanted), seed=7)
        until: cf.Future[int] = cf.Future()
        net = _net()
        ahead = train_ahead(net, x, y, config, until=until, seed=7)
        until.set_result(wanted)
        if schedule == "cosine" and wanted != 5:  # a bet on the whole length, lost
            assert not ahead.cut(net, wanted)
            continue
        assert ahead.cut(net, wanted)
        assert ahead.history.train_loss == expected.train_loss
        assert ahead.history.best_epoch == expected.best_epoch
        assert all(
            np.array_equal(p, q) for p, q in zip(_weights(net), _weights(alone), strict=True)
        )


def test_a_run_ahead_stops_once_its_length_is_known() -> None:
    x, y = _windows(2)
    config = Training(epochs=6, batch_size=32, device="cpu", patience=None, val_fraction=0.0)
    known: cf.Future[int] = cf.Future()
    known.set_result(2)
    ahead = train_ahead(_net(), x, y, config, until=known, seed=1)
    assert len(ahead.history.train_loss) == 2
    wrong: cf.Future[int] = cf.Future()
    wrong.set_result(2)
    cosine = train_ahead(_net(), x, y, config.replace(schedule="cosine"), until=wrong, seed=1)
    assert cosine.history.train_loss == []  # the bet on 6 epochs is lost before it starts


def _record(seed: int, bias: float) -> MeasurementSeries:
    rng = np.random.default_rng(seed)
    time_s = np.arange(N) * 0.02
    u = np.repeat(rng.normal(0.0, 1.0, N // 40 + 1), 40)[:N]
    y = (np.sin(2 * np.pi * 0.4 * time_s) + 0.5 * u + bias + 0.3 * np.tanh(2 * u))[:, None]
    y = y + rng.normal(0.0, 0.05, (N, 1))
    return MeasurementSeries(time_s, y, channels=("y",), inputs={"u": u})


def _physics() -> MechanisticModel:
    def run(series: MeasurementSeries) -> np.ndarray:
        return (np.sin(2 * np.pi * 0.4 * series.time_s) + 0.5 * series.inputs["u"])[:, None]

    return MechanisticModel.from_series_function(run, channels=("y",), name="physics")


# each final net ends before its 6 epochs, so its judges, trained ahead, are cut back (a
# constant rate) or trained again (a cosine one: the bet on 6 epochs lost)
@pytest.mark.parametrize(("task", "schedule", "lr"), [("simulation", "constant", 0.1),
                                                      ("prediction", "cosine", 0.1),
                                                      ("prediction", "constant", 1e-3)])  # fmt: skip
def test_a_hybrid_fits_the_same_numbers_side_by_side_as_one_after_the_other(
    task: str, schedule: str, lr: float, monkeypatch: pytest.MonkeyPatch
) -> None:
    a, b = _record(1, 0.2), _record(2, -0.1)
    data = MeasurementSeries.concat([a, b]) if task == "simulation" else a
    hyper = {**TINY, "epochs": 6, "patience": 2, "task": task, "outputs": ("y",),
             "inputs": ("u",), "seed": 3, "schedule": schedule, "dropout": 0.2, "lr": lr}  # fmt: skip
    if task == "simulation":
        hyper["init_samples"] = 8
    fitted = {}
    for workers in ("1", "2"):
        monkeypatch.setenv(WORKERS_ENV, workers)
        fitted[workers] = make_model("parallel", **hyper).fit(data, _physics())
    one, two = fitted["1"], fitted["2"]
    assert json.dumps(one.selection_, sort_keys=True, default=str) == json.dumps(
        two.selection_, sort_keys=True, default=str)  # fmt: skip
    assert one.history_.train_loss == two.history_.train_loss
    assert all(np.array_equal(p, q)
               for p, q in zip(_weights(one.net_), _weights(two.net_), strict=True))  # fmt: skip
    assert "fold_nrmse" in one.selection_["correction"]
    assert one.history_.best_epoch + 1 < 6


def test_side_by_side_runs_jobs_at_once_and_returns_them_in_order() -> None:
    both = threading.Barrier(2, timeout=10)

    def job(k: int) -> int:
        both.wait()  # returns only when the other job runs at the same time
        return k * 10

    assert side_by_side([lambda: job(1), lambda: job(2)], workers=2) == [10, 20]
    assert side_by_side([lambda: 1, lambda: 2, lambda: 3], workers=1) == [1, 2, 3]


def _spinning(stopped: list[str], name: str) -> int:
    while True:
        try:
            check_cancelled()
        except BaseException:
            stopped.append(name)
            raise
        time.sleep(0.01)


def test_a_failing_job_stops_the_others_and_its_error_is_raised() -> None:
    stopped: list[str] = []

    def fails() -> int:
        time.sleep(0.2)
        raise DataError("only 1 usable training window")

    start = time.monotonic()
    with pytest.raises(DataError, match="usable training window"):
        side_by_side([lambda: _spinning(stopped, "long"), fails], workers=2)
    assert stopped == ["long"] and time.monotonic() - start < 3


class _Stop(Exception):
    pass


def test_an_interruption_of_the_waiting_thread_stops_every_job() -> None:
    stopped: list[str] = []

    def interrupt(signum: int, frame: object) -> None:
        raise _Stop

    old = signal.signal(signal.SIGALRM, interrupt)
    signal.setitimer(signal.ITIMER_REAL, 0.3)
    start = time.monotonic()
    try:
        with pytest.raises(_Stop):
            side_by_side([lambda: _spinning(stopped, "a"), lambda: _spinning(stopped, "b")],
                         workers=2)  # fmt: skip
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    assert sorted(stopped) == ["a", "b"] and time.monotonic() - start < 3


def test_training_workers_follow_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(PARALLEL_TASK_ENV, raising=False)
    monkeypatch.delenv("DRAFTTWIN_THREADS", raising=False)
    monkeypatch.setenv(WORKERS_ENV, "3")
    assert training_workers() == 3
    for bad in ("0", "9", "two"):
        monkeypatch.setenv(WORKERS_ENV, bad)
        with pytest.raises(ConfigError, match=WORKERS_ENV):
            training_workers()
    monkeypatch.delenv(WORKERS_ENV)
    monkeypatch.setenv(PARALLEL_TASK_ENV, "1")
    assert training_workers() == 1  # its siblings have the other CPUs
    monkeypatch.delenv(PARALLEL_TASK_ENV)
    monkeypatch.setenv("DRAFTTWIN_THREADS", "2")
    assert training_workers() == 1


def test_workers_of_a_parallel_run_are_marked_and_the_parent_is_not(tmp_path) -> None:
    out = run_tasks(parallel_task_mark, [{"k": 0}, {"k": 1}], workers=2)
    assert [r["parallel_task"] for r in out] == [True, True]
    assert run_tasks(parallel_task_mark, [{"k": 0}], workers=1)[0]["parallel_task"] is False


def test_deterministic_algorithms_stay_on_until_the_last_training_leaves() -> None:
    before = torch.are_deterministic_algorithms_enabled()
    entered, leave = threading.Event(), threading.Event()

    def other() -> None:
        with compute_context(torch.device("cpu")):
            entered.set()
            leave.wait(10)

    thread = threading.Thread(target=other)
    with compute_context(torch.device("cpu")):
        thread.start()
        entered.wait(10)
    assert torch.are_deterministic_algorithms_enabled()  # the other training still runs
    leave.set()
    thread.join(10)
    assert torch.are_deterministic_algorithms_enabled() == before


def test_stages_side_by_side_get_a_bar_each_and_hand_them_on() -> None:
    progress = FitProgress("fit", quiet=True)
    both = threading.Barrier(2, timeout=10)

    def stage(name: str) -> None:
        progress.stage(name, 2)
        both.wait()
        progress.finish()

    side_by_side([lambda: stage("a"), lambda: stage("b")], workers=2)
    assert len(progress._progress.tasks) == 2
    progress.stage("c", 1)
    progress.finish()
    assert len(progress._progress.tasks) == 2  # a free bar is taken again


def test_a_judge_too_big_to_keep_per_epoch_waits_for_its_length(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from drafttwin.models.estimators import folds

    data = _record(1, 0.2)
    hyper = {**TINY, "epochs": 6, "patience": 2, "task": "prediction", "outputs": ("y",),
             "inputs": ("u",), "seed": 3, "schedule": "constant", "dropout": 0.2}  # fmt: skip
    monkeypatch.setenv(WORKERS_ENV, "1")
    alone = make_model("parallel", **hyper).fit(data, _physics())
    monkeypatch.setenv(WORKERS_ENV, "2")
    monkeypatch.setattr(folds, "AHEAD_BYTES", 0)
    ahead: list[str] = []
    monkeypatch.setattr(folds, "train_ahead", lambda *a, **k: ahead.append("ran") or None)
    waited = make_model("parallel", **hyper).fit(data, _physics())
    assert ahead == []
    assert alone.selection_ == waited.selection_
    assert all(np.array_equal(p, q)
               for p, q in zip(_weights(alone.net_), _weights(waited.net_), strict=True))  # fmt: skip
