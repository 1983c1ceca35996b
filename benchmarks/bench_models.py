"""Benchmark of the model library (CPU by default).

1. Training throughput (training samples per second, validation included) of the GRU and the
   MD-S-L residual network through ``drafttwin.models.train_network`` versus a bare PyTorch
   loop doing the same work (same network, data, batches, Adam, clipping, one validation pass
   per epoch). Overhead ratio = bare throughput / our throughput (target <= 1.1).
2. Single-step prediction latency of a fitted MD-S-L (p50/p99 in ms, target p99 <= 5 ms) at the
   ``quick`` and ``paper`` sizes: a streaming step of ``OnlinePredictor`` (``forecast`` the next
   row: one residual-net pass, the latency; then ``observe`` its measurement: one GRU pass for
   the next data-driven residual), the public ``predict`` on the
   shortest history that yields one prediction (recomputes the GRU over the whole residual
   window), and the residual network's forward pass alone.

Prints a table and writes ``benchmarks/results/models.json`` (figure, value, unit, machine,
date). Run: ``python benchmarks/bench_models.py [--threads 1] [--epochs 3]``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

from drafttwin._io import write_text_atomic
from drafttwin.data.series import MeasurementSeries
from drafttwin.models import (
    MDSL,
    MechanisticModel,
    OnlinePredictor,
    TrainConfig,
    make_model,
    train_network,
)
from drafttwin.models.estimators.networks import RecurrentRegressor, ResidualNet
from drafttwin.models.training import split_sizes

BASE_RPM = np.array([1815.0, 435.0, 426.0, 355.0])
RESULTS = Path(__file__).parent / "results" / "models.json"


def mechanistic(time_s: np.ndarray) -> np.ndarray:
    """A stand-in mechanistic prediction (n, 4) rpm."""
    t = np.asarray(time_s)[:, None]
    return BASE_RPM * (1.002 + 0.002 * np.sin(2 * np.pi * t / 0.37 + np.arange(4)))


def synthetic(n: int, seed: int = 0) -> MeasurementSeries:
    """Speeds around 1815/435/426/355 rpm: sinusoids, AR(1) fluctuation, white noise."""
    rng = np.random.default_rng(seed)
    time_s = np.arange(n) * 0.01
    t = time_s[:, None]
    clean = BASE_RPM * (1 + 0.002 * np.sin(2 * np.pi * t / 0.37 + np.arange(4)))
    clean += BASE_RPM * 0.003 * np.sin(2 * np.pi * t / 2.3)
    ar = np.zeros((n, 4))
    shocks = rng.normal(0, 4e-4, (n, 4)) * BASE_RPM
    for i in range(1, n):
        ar[i] = 0.9 * ar[i - 1] + shocks[i]
    return MeasurementSeries(time_s, clean + ar + rng.normal(0, 2e-4, (n, 4)) * BASE_RPM)


# ----- training throughput ---------------------------------------------------------------
def bare_loop(net: nn.Module, x: np.ndarray, y: np.ndarray, cfg: TrainConfig) -> float:
    """The same work as train_network, written plainly; returns seconds."""
    start = time.perf_counter()
    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    n_train, _ = split_sizes(len(x), cfg.val_fraction)
    xt, yt = torch.from_numpy(x), torch.from_numpy(y)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    for _ in range(cfg.epochs):
        net.train()
        perm = torch.randperm(n_train, generator=gen)
        for i in range(0, n_train, cfg.batch_size):
            idx = perm[i : i + cfg.batch_size]
            opt.zero_grad()
            loss = nn.functional.mse_loss(net(xt[idx]), yt[idx])
            loss.backward()
            nn.utils.clip_grad_norm_(net.parameters(), cfg.clip_norm or 1.0)
            opt.step()
        net.eval()
        with torch.no_grad():
            nn.functional.mse_loss(net(xt[n_train:]), yt[n_train:])
    return time.perf_counter() - start


def throughput(name: str, make_net, x: np.ndarray, y: np.ndarray, epochs: int, reps: int):
    """Best-of-``reps`` samples/s of our loop and of the bare loop."""
    cfg = TrainConfig(epochs=epochs, batch_size=64, patience=None, device="cpu")
    n_train, _ = split_sizes(len(x), cfg.val_fraction)
    ours, bare = [], []
    for _ in range(reps):
        torch.manual_seed(0)
        hist = train_network(make_net(), x, y, cfg)
        ours.append(hist.seconds)
        torch.manual_seed(0)
        bare.append(bare_loop(make_net(), x, y, cfg))
    ours_sps = n_train * epochs / min(ours)
    bare_sps = n_train * epochs / min(bare)
    return [
        (f"train throughput {name} (drafttwin loop)", ours_sps, "samples/s"),
        (f"train throughput {name} (bare PyTorch loop)", bare_sps, "samples/s"),
        (f"train overhead ratio {name} (bare/ours)", bare_sps / ours_sps, "ratio"),
    ]


# ----- single-step latency ---------------------------------------------------------------
def fitted_mdsl(profile: str, series: MeasurementSeries) -> MDSL:
    """An MD-S-L of the profile's size, fitted briefly (latency does not depend on training)."""
    model = make_model(
        "md-s-l", profile=profile, epochs=1, folds=2, batch_size=64, device="cpu", quiet=True
    )
    assert isinstance(model, MDSL)
    return model.fit(series, MechanisticModel(mechanistic))


def percentiles(samples: list[float]) -> tuple[float, float]:
    arr = np.asarray(samples) * 1e3
    return float(np.percentile(arr, 50)), float(np.percentile(arr, 99))


def online_steps(model: MDSL, mech: MechanisticModel, series: MeasurementSeries, runs: int):
    """Seconds per streaming step: (forecast the next row, then observe its measurement)."""
    online = OnlinePredictor(model, mech)
    online.observe_series(series.slice(0, 100))
    fc, ob = [], []
    for i in range(runs + 20):
        row = 100 + i % (len(series) - 100)
        t0 = time.perf_counter()
        yhat = online.forecast(float(series.time_s[row]))
        t1 = time.perf_counter()
        online.observe(float(series.time_s[row]), series.values[row])
        fc.append(t1 - t0)
        ob.append(time.perf_counter() - t1)
    assert np.isfinite(yhat).all()
    return fc[20:], ob[20:]


def latency(profile: str, series: MeasurementSeries, runs: int):
    model = fitted_mdsl(profile, series)
    mech = MechanisticModel(mechanistic)
    need = model.data_window + model.window + 2 * model.horizon - 1
    tail = series.slice(len(series) - need)
    assert np.isfinite(model.predict_values(tail, mech)[-1]).all()
    api, net = [], []
    x = torch.randn(1, model.window, 8)
    for i in range(runs + 20):
        t0 = time.perf_counter()
        model.predict_values(tail, mech)
        t1 = time.perf_counter()
        with torch.inference_mode():
            model.net_(x)
        t2 = time.perf_counter()
        if i >= 20:
            api.append(t1 - t0)
            net.append(t2 - t1)
    a50, a99 = percentiles(api)
    n50, n99 = percentiles(net)
    fc, ob = online_steps(model, mech, series, runs)
    f50, f99 = percentiles(fc)
    o50, o99 = percentiles(ob)
    s50, s99 = percentiles([a + b for a, b in zip(fc, ob, strict=True)])
    return [
        (f"md-s-l {profile} online forecast() p50", f50, "ms"),
        (f"md-s-l {profile} online forecast() p99", f99, "ms"),
        (f"md-s-l {profile} online observe() p50", o50, "ms"),
        (f"md-s-l {profile} online observe() p99", o99, "ms"),
        (f"md-s-l {profile} online step (forecast+observe) p50", s50, "ms"),
        (f"md-s-l {profile} online step (forecast+observe) p99", s99, "ms"),
        (f"md-s-l {profile} predict() one step p50", a50, "ms"),
        (f"md-s-l {profile} predict() one step p99", a99, "ms"),
        (f"md-s-l {profile} residual-net forward p50", n50, "ms"),
        (f"md-s-l {profile} residual-net forward p99", n99, "ms"),
    ]


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    return (
        f"{platform.node()} {cpu}, {os.cpu_count()} cores, torch {torch.__version__}, "
        f"{torch.get_num_threads()} thread(s), CPU"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    parser.add_argument("--epochs", type=int, default=3, help="epochs per throughput run")
    parser.add_argument("--reps", type=int, default=3, help="repetitions (best is kept)")
    parser.add_argument("--runs", type=int, default=300, help="latency samples per figure")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    rng = np.random.default_rng(0)
    n = 2000
    x_gru = rng.random((n, 20, 4)).astype(np.float32)
    x_res = rng.random((n, 20, 8)).astype(np.float32)
    y = rng.random((n, 4)).astype(np.float32)
    rows = throughput(
        "gru quick (2x48)",
        lambda: RecurrentRegressor(4, 4, hidden=48, layers=2, dropout=0.1),
        x_gru, y, args.epochs, args.reps,
    )  # fmt: skip
    rows += throughput(
        "md-s-l net quick (SK24 + LSTM 1x48)",
        lambda: ResidualNet(8, 4, sk_channels=24, hidden=48, layers=1, dropout=0.1),
        x_res, y, args.epochs, args.reps,
    )  # fmt: skip
    series = synthetic(400)
    rows += latency("quick", series, args.runs)
    rows += latency("paper", series, args.runs)

    now = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    host = machine()
    print(f"{'figure':66s} {'value':>12s}  unit")
    for fig, value, unit in rows:
        print(f"{fig:66s} {value:12.3f}  {unit}")
    records = [
        {"figure": f, "value": round(v, 4), "unit": u, "machine": host, "date": now}
        for f, v, u in rows
    ]
    write_text_atomic(args.out, json.dumps(records, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
