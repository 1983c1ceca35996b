"""``drafttwin fit``, ``predict`` and ``evaluate``: the models on measured data."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.table import Table

from drafttwin.cli._common import write_frame
from drafttwin.cli.app import app, console
from drafttwin.errors import DataError

DataOpt = Annotated[
    str,
    typer.Option("--data", help="'default' (embedded FA320A plant data) or a CSV/Parquet file."),
]
MechOpt = Annotated[
    str | None,
    typer.Option("--mechanistic", help="'preset' (fa320a), 'preset:NAME', or a simulator output "
                 "file (time + roller rpm). Default: the source recorded in the model file."),
]  # fmt: skip
ModelFileOpt = Annotated[
    Path, typer.Option("--model", help="A model file written by 'fit'.", dir_okay=False)
]
FractionOpt = Annotated[
    float,
    typer.Option(
        help="Chronological share used for fitting; the rest is the test part.", min=0.05, max=0.95
    ),
]


def load_data(data: str):
    """The series named by ``--data`` (``default`` or a file path)."""
    if data == "default":
        from drafttwin.datasets import load_default

        return load_default()
    from drafttwin.data.io import read_measurements
    from drafttwin.plant.emulator import attach_truth

    return attach_truth(read_measurements(Path(data)), Path(data))


def mechanistic_source(spec: str | None):
    from drafttwin.models import MechanisticModel

    if spec is None:
        return None
    if spec == "preset" or spec.startswith("preset:"):
        return MechanisticModel.from_preset(spec.partition(":")[2] or "fa320a")
    return MechanisticModel(Path(spec))


def _check_rate(model, series, source: str) -> None:
    rate = getattr(model, "sample_rate_hz_", None)
    if rate and not np.isclose(series.sample_rate_hz, rate, rtol=0.01):
        raise DataError(
            f"the data are sampled at {series.sample_rate_hz:g} Hz but the model was fitted at {rate:g} Hz",
            source=source,
            fix="resample the data to the model's rate, or fit a model on data at this rate",
        )


@app.command()
def fit(
    model: Annotated[
        str,
        typer.Option(
            help="mechanistic | persistence | gru | lstm | parallel | md-s-l | md-l | md-s | md-s-l+d"
        ),
    ],
    out: Annotated[
        Path, typer.Option(help="Model file to write (weights, scalers, config).", dir_okay=False)
    ],
    data: DataOpt = "default",
    mechanistic: MechOpt = None,
    profile: Annotated[
        str, typer.Option(help="quick | standard | paper (hyperparameters).")
    ] = "quick",
    train_fraction: FractionOpt = 0.7,
    seed: Annotated[int, typer.Option(help="Seed: same seed, same numbers on CPU.")] = 0,
    horizon: Annotated[int, typer.Option(help="Predict t+h-1 from data up to t-1.", min=1)] = 1,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
) -> None:
    """Fit a model on the first part of a data set (preprocessed as in the paper) and save it."""
    from drafttwin.data.preprocess import preprocess
    from drafttwin.models import make_model

    estimator = make_model(model, profile, seed=seed, horizon=horizon, quiet=quiet) if model not in (
        "mechanistic", "persistence") else make_model(model, profile, horizon=horizon)  # fmt: skip
    series = load_data(data)
    n_train = int(round(train_fraction * len(series)))
    train, report = preprocess(series.slice(0, n_train))
    mech = mechanistic_source(mechanistic or ("preset" if estimator.needs_mechanistic else None))
    estimator.fit(train, mech)
    estimator.save(out)
    console.print(f"fitted {model} on {n_train} samples ({report.to_dict()['filled']} filled, "
                  f"{report.to_dict()['outliers']} outliers smoothed); wrote {out}")  # fmt: skip


@app.command()
def predict(
    model: ModelFileOpt,
    out: Annotated[Path, typer.Option(help="Predictions, .csv or .parquet.", dir_okay=False)],
    data: DataOpt = "default",
    mechanistic: MechOpt = None,
) -> None:
    """Predict roller speeds for every sample of a data set (each from earlier samples only)."""
    import pandas as pd

    from drafttwin.models import load_model

    estimator = load_model(model)
    series = load_data(data)
    _check_rate(estimator, series, data)
    pred = estimator.predict_values(series, mechanistic_source(mechanistic))
    frame = pd.DataFrame(
        {"time": series.time_s, **{r: pred[:, j] for j, r in enumerate(series.channels)}}
    )
    write_frame(frame, out)
    console.print(f"wrote {len(frame)} predictions to {out}")


def _metrics_table(metrics: dict, title: str) -> Table:
    """One row per channel; the unit in the headers when the channels share one, else in a
    column of its own."""
    units = {m.unit for m in metrics.values()}
    shared = units.pop() if len(units) == 1 else None

    def head(label: str) -> str:
        return f"{label} {shared}" if shared else label

    table = Table(title=title)
    table.add_column("channel")
    if shared is None:
        table.add_column("unit")
    for c in ("max rel %", "mean rel %", "accuracy %", head("RMSE"), "NRMSE", "skill",
              head("noise floor")):  # fmt: skip
        table.add_column(c, justify="right")
    for r, m in metrics.items():
        cells = [f"{m.max_rel_err_pct:.4f}", f"{m.mean_rel_err_pct:.4f}", f"{m.accuracy_pct:.3f}",
                 f"{m.rmse:.4g}", f"{m.nrmse:.3f}", f"{m.skill:.3f}", f"{m.noise_floor:.4g}"]  # fmt: skip
        table.add_row(r, *([] if shared is not None else [m.unit]), *cells)
    return table


@app.command()
def evaluate(
    model: ModelFileOpt,
    data: DataOpt = "default",
    mechanistic: MechOpt = None,
    train_fraction: FractionOpt = 0.7,
    as_json: Annotated[
        bool,
        typer.Option("--json", help="One JSON object keyed by channel (null: not computable)."),
    ] = False,
) -> None:
    """Score a model on the test part of a data set (after --train-fraction): the paper's
    relative errors and honest metrics (RMSE, NRMSE, skill vs persistence, noise floor)."""
    from drafttwin.data.preprocess import preprocess, reject_spikes_causal
    from drafttwin.evaluation.metrics import evaluate as score
    from drafttwin.evaluation.metrics import persistence_forecast
    from drafttwin.models import load_model

    estimator = load_model(model)
    series = load_data(data)
    _check_rate(estimator, series, data)
    n_train = int(round(train_fraction * len(series)))
    train, _ = preprocess(series.slice(0, n_train))
    test_inputs, _ = reject_spikes_causal(series.slice(n_train))
    inputs = series.with_values(np.vstack([train.values, test_inputs]))
    _, full = preprocess(series)
    target = np.where(np.isnan(series.values) | full.outliers, np.nan, series.values)[n_train:]
    pred = estimator.predict_values(inputs, mechanistic_source(mechanistic))[n_train:]
    true = series.metadata.get("true_rpm")  # the plant emulator's truth, one column per roller
    true_ok = true is not None and np.shape(true) == series.values.shape
    units = {c: series.unit(c) for c in series.channels}
    metrics = score(target, pred, channels=series.channels, units=units,
                    persistence=persistence_forecast(inputs.values, getattr(estimator, "horizon", 1))[n_train:],
                    true_values=np.asarray(true)[n_train:] if true_ok else None)  # fmt: skip
    if as_json:
        typer.echo(json.dumps({r: m.to_dict() for r, m in metrics.items()}, indent=2,
                              allow_nan=False))  # fmt: skip
        return
    console.print(
        _metrics_table(metrics, f"{estimator.name} on the test part ({len(target)} samples)")
    )
    for r, m in metrics.items():
        if m.rel_note:
            console.print(f"{r}: {m.rel_note}")
    console.print(
        "skill = 1 - RMSE / RMSE(persistence); scored: measured samples not flagged as outliers"
    )
