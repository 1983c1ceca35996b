"""``drafttwin fit``, ``predict`` and ``evaluate``: the models on measured data, any machine."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import numpy as np
import typer
from rich.markup import escape
from rich.table import Table

from drafttwin.cli._common import write_frame
from drafttwin.cli._data import ChannelOptions
from drafttwin.cli._groups import with_group
from drafttwin.cli._modelopts import SetOpt, cli_terms, new_model, parse_settings, setting_names
from drafttwin.cli._options import (
    EpochsOpt,
    FullModelOpt,
    InitOpt,
    MechanisticOpt,
    TaskOpt,
    TestDataOpt,
    file_in,
    file_out,
    files_in,
    number,
)
from drafttwin.cli.app import app, console, err_console, print_json
from drafttwin.errors import ConfigError, DataError

if TYPE_CHECKING:
    from drafttwin.data.series import MeasurementSeries
    from drafttwin.evaluation.metrics import ChannelMetrics
    from drafttwin.evaluation.protocol import Evaluation
    from drafttwin.models import BaseModel, MechanisticModel

ModelKindOpt = Annotated[str, typer.Option("--model", help="mechanistic | persistence | gru | "
                         "lstm | parallel | md-s-l | md-l | md-s | md-s-l+d")]  # fmt: skip
ModelFileOpt = Annotated[Path, file_in("--model", "A model file written by 'fit'.")]
ModelOutOpt = Annotated[Path, file_out("--out", "Model file to write (weights, scalers, config).")]  # fmt: skip
PredictionsOutOpt = Annotated[Path, file_out("--out", "Predictions, .csv or .parquet.")]
ProfileOpt = Annotated[str | None, typer.Option("--profile", help="quick | standard | paper: the "
                       "networks' hyperparameters (default quick).")]  # fmt: skip
FractionOpt = Annotated[float | None, number(
    "--train-fraction", "Chronological share of --data that trains; the rest is the test part "
    "(default 0.7 for fit, the model's own for evaluate; 1 on fit: all of it, no test part). "
    "Not with --test-data.")]  # fmt: skip
SeedOpt = Annotated[int | None, number("--seed", "Seed of the networks (default 0): same seed, "
                    "same numbers on CPU.")]  # fmt: skip
HorizonOpt = Annotated[int, number("--horizon", "Predict t+h-1 from data up to t-1.")]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print one JSON object: metrics per channel "
                    "(null: not computable), the task and the options chosen on validation data.")]  # fmt: skip
WrittenJsonOpt = Annotated[bool, typer.Option("--json", help="Print what was written as one JSON object.")]  # fmt: skip
QuietOpt = Annotated[
    bool, typer.Option("--quiet", help="No progress bar and no notes; results only.")
]
ScoreFromOpt = Annotated[int, number("--score-from", "Score each test record from this sample on "
                         "(0-based: the first N samples are not scored), as a published protocol "
                         "says.")]  # fmt: skip
FreeRunOpt = Annotated[
    str,
    typer.Option("--free-run-from",
                 help="Simulation after a chronological split: 'test' (default) runs free from "
                 "the test part's own first --init-samples samples; 'start' from the start of "
                 "the record (the training rows run free too; the test part is scored)."),
]  # fmt: skip


def _source(
    option: str | None, model: BaseModel, channels: tuple[str, ...] | None, full: bool = False
) -> MechanisticModel | None:
    """The mechanistic source of ``--mechanistic``, else the model's own (or the FA320A
    preset for a new hybrid on the roller channels). A new model's drive train is reduced
    unless ``full`` (``--full-model``); a fitted model's is simulated as it was fitted."""
    from drafttwin._constants import ROLLERS
    from drafttwin.mechanics import DEFAULT_CUTOFF_HZ
    from drafttwin.models import MechanisticModel
    from drafttwin.models.mechanistic import describe_spec, spec_cutoff_hz

    if not model.needs_mechanistic:
        if option is not None:
            raise ConfigError(f"the {model.name} model uses no mechanistic source",
                              where="--mechanistic", fix="leave --mechanistic out")  # fmt: skip
        return None
    fitted = getattr(model, "mechanistic_spec_", None)
    is_fitted = hasattr(model, "channels_")
    cutoff_hz = spec_cutoff_hz(fitted) if is_fitted else (None if full else DEFAULT_CUTOFF_HZ)
    if option is not None:
        return MechanisticModel.from_option(option, cutoff_hz=cutoff_hz)
    if is_fitted:
        source = MechanisticModel.from_spec(fitted)
        if source is None:
            raise ConfigError(
                f"the model was fitted with {describe_spec(fitted)}, which the model file does "
                "not hold",
                where="--mechanistic",
                fix="pass the mechanistic source again with --mechanistic",
            )
        return source
    if channels not in (None, ROLLERS):
        raise ConfigError(
            f"the {model.name} model needs the physics of the channels {', '.join(channels)}",
            where="--mechanistic",
            fix="give config:YOUR_TRAIN.toml or a simulator output file (time + those columns)",
        )
    return MechanisticModel.from_preset("fa320a", cutoff_hz=cutoff_hz)


def _check_task(model: BaseModel, task: str | None, init_samples: int | None) -> None:
    """``--task`` / ``--init-samples`` on predict and evaluate must match the model file."""
    if task is not None and task != model.task.kind:
        raise ConfigError(f"--task {task} but the model was fitted for {model.task.kind!r}",
                          where="--task", fix="leave --task out, or fit a model for that task")  # fmt: skip
    if init_samples is not None and init_samples != model.task.init_samples:
        raise ConfigError(
            f"--init-samples {init_samples} but the model was fitted with "
            f"{model.task.init_samples}",
            where="--init-samples",
            fix="leave --init-samples out (the free-run start is part of the model)",
        )


def _check_rate(model: BaseModel, series: MeasurementSeries, source: str) -> None:
    rate = getattr(model, "sample_rate_hz_", None)
    if rate and not np.isclose(series.sample_rate_hz, rate, rtol=0.01):
        raise DataError(
            f"the data are sampled at {series.sample_rate_hz:g} Hz but the model was fitted at "
            f"{rate:g} Hz",
            source=source,
            fix="resample the data to the model's rate, or fit a model on data at this rate",
        )


def _selection_lines(selection: dict[str, Any]) -> list[str]:
    lines = []
    choice = selection.get("accumulate")
    if choice:
        what = "accumulated changes" if choice["accumulate"] else "residual level"
        scores = ", ".join(f"{k} {v:.3g}" for k, v in choice.get("validation_nrmse", {}).items()
                           if v is not None)  # fmt: skip
        how = f"chosen on validation data (free-run NRMSE: {scores})" if scores else "set"
        lines.append(f"residual model predicts the {what}: {how}")
    correction = selection.get("correction")
    if correction:
        scores = ", ".join(f"{_CANDIDATE.get(k, k)} {v:.3g}"
                           for k, v in correction.get("validation_nrmse", {}).items()
                           if v is not None)  # fmt: skip
        kept = correction["kept"]
        lines.append(
            ("no correction: the physics alone predicts (the residual model did not beat it"
             if kept == "none" else f"correction kept: {_CANDIDATE.get(kept, kept)} ("
             + ("beats the physics alone" if correction["chosen_by"] == "validation"
                else "kept by --set fallback=false" if correction["chosen_by"] == "user"
                else "no validation part to test it on"))
            + (f"; validation NRMSE: {scores})" if scores else ")")
        )  # fmt: skip
    return lines


_CANDIDATE = {"none": "physics alone", "level": "residual level",
              "accumulate": "accumulated changes", "residual": "residual model"}  # fmt: skip
"""How the validation candidates of a hybrid read in the report."""


ModelDataOpt = Annotated[str | None, files_in(
    "--data", "'default' (the embedded FA320A plant data) or CSV/Parquet file(s), comma-separated "
    "(separate experiments: no model window crosses from one to the next). fit: default "
    "'default'; predict / evaluate: default the data the model was fitted on (its file "
    "records it).")]  # fmt: skip


@dataclass(frozen=True)
class SourceOptions:
    """Where the data and the physics come from, and the task (fit, predict, evaluate)."""

    data: ModelDataOpt = None
    test_data: TestDataOpt = None
    mechanistic: MechanisticOpt = None
    task: TaskOpt = None
    init_samples: InitOpt = None

    def refuse_fraction_with_test_data(self, train_fraction: float | None) -> None:
        if self.test_data is not None and train_fraction is not None:
            raise ConfigError("--train-fraction splits --data, but --test-data is given",
                              where="--train-fraction",
                              fix="with --test-data every row of --data trains: drop "
                              "--train-fraction")  # fmt: skip

    @property
    def fit_data(self) -> str:
        """fit: --data, else the embedded FA320A data."""
        return self.data or "default"

    def spec(self, fitted_on: str | None = None) -> str:
        """predict / evaluate: --test-data replaces --data; with neither, the data the model
        was fitted on (``fitted_on``, from its file), else the embedded data."""
        if self.test_data is None:
            return self.data or fitted_on or "default"
        if self.data is not None:
            raise ConfigError("--test-data replaces --data here; both were given",
                              where="--data / --test-data", fix="give one of them")  # fmt: skip
        return self.test_data


@app.command()
@with_group("channels", ChannelOptions)
@with_group("source", SourceOptions)
def fit(
    model: ModelKindOpt, out: ModelOutOpt, source: SourceOptions, channels: ChannelOptions,
    profile: ProfileOpt = None, train_fraction: FractionOpt = None, seed: SeedOpt = None,
    horizon: HorizonOpt = 1, epochs: EpochsOpt = None, settings: SetOpt = None,
    full_model: FullModelOpt = False, quiet: QuietOpt = False, as_json: JsonOpt = False,
) -> None:  # fmt: skip
    """Fit a model and save it. Trains on the first --train-fraction of --data (preprocessed as
    in the paper; 'drafttwin evaluate' then scores the rest), or on all of --data when separate
    --test-data records are given: these are scored at once and the metrics printed."""
    from drafttwin.evaluation import protocol

    source.refuse_fraction_with_test_data(train_fraction)
    parsed = channels.parse()
    estimator, notes = new_model(model, profile=profile, task=source.task,
                                 init=source.init_samples, horizon=horizon, channels=parsed,
                                 seed=seed, quiet=quiet, epochs=epochs,
                                 settings=parse_settings(settings))  # fmt: skip
    if not quiet:
        for note in notes:
            err_console.print(f"note: {escape(note)}", highlight=False, soft_wrap=True)
    physics = _source(source.mechanistic, estimator, parsed.outputs, full_model)
    if full_model and not quiet and (physics is None
                                     or physics.spec()["kind"] not in ("preset", "train")):  # fmt: skip
        what = "uses no physics" if physics is None else "takes its physics from files"
        err_console.print(f"note: --full-model changes nothing: the {estimator.name} model {what}",
                          highlight=False, soft_wrap=True)  # fmt: skip
    needs = () if physics is None else physics.required_inputs()
    series = parsed.read(source.fit_data, needs)
    test = None if source.test_data is None else parsed.read(source.test_data, needs)
    fraction = None if test is not None else (train_fraction or 0.7)
    with cli_terms(setting_names(model)):
        part = protocol.fit_split(estimator, series, train_fraction=fraction, test=test,
                                      mechanistic=physics)  # fmt: skip
    estimator.provenance_["data"] = source.fit_data
    estimator.save(out)
    pre = part.summary["preprocessing"]["train"]
    filled, smoothed = sum(pre["filled"].values()), sum(pre["outliers"].values())
    (err_console if as_json or quiet else console).print(  # --json: stdout holds the JSON
        f"fitted {estimator.name} ({estimator.task.kind}) on {part.summary['train_rows']} rows "
        f"in {part.summary['train_records']} record(s), channels {', '.join(estimator.channels_)} "
        f"({filled} samples filled, {smoothed} outliers smoothed); wrote {escape(str(out))}"
    )
    if test is not None:  # separate test records: score them now (else: drafttwin evaluate)
        _report(protocol.evaluate(estimator, part, mechanistic=physics), as_json)
        return
    if as_json:
        print_json({"model": estimator.name, "selection": estimator.selection_,
                    "split": part.summary})  # fmt: skip
        return
    for line in _selection_lines(estimator.selection_):
        console.print(line)


def _fitted(
    model_file: Path, source: SourceOptions, channels: ChannelOptions, quiet: bool
) -> tuple[BaseModel, MechanisticModel | None, MeasurementSeries]:
    """A model file, its physics and the data of predict / evaluate, checked against it."""
    import warnings

    from drafttwin.models import load_model
    from drafttwin.models.modelfile import DeviceFallbackWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DeviceFallbackWarning)
        estimator = load_model(model_file)
    for warning in caught:  # one line each (e.g. a model saved for cuda, run on the cpu)
        if issubclass(warning.category, DeviceFallbackWarning):
            err_console.print(f"[yellow]warning:[/] {escape(str(warning.message))}",
                              highlight=False, soft_wrap=True)  # fmt: skip
        else:
            warnings.warn_explicit(warning.message, warning.category, warning.filename,
                                   warning.lineno)  # fmt: skip
    _check_task(estimator, source.task, source.init_samples)
    parsed = channels.parse().for_model(estimator)
    physics = _source(source.mechanistic, estimator, parsed.outputs)
    fitted_on = estimator.provenance_.get("data")
    spec = source.spec(fitted_on if isinstance(fitted_on, str) else None)
    if source.data is None and source.test_data is None and spec != "default" and not quiet:
        err_console.print(f"note: --data not given: the data {escape(model_file.name)} was "
                          f"fitted on, {escape(spec)}", highlight=False, soft_wrap=True)  # fmt: skip
    series = parsed.read(spec, () if physics is None else physics.required_inputs())
    _check_rate(estimator, series, spec)
    return estimator, physics, series


@app.command()
@with_group("channels", ChannelOptions)
@with_group("source", SourceOptions)
def predict(
    model: ModelFileOpt, out: PredictionsOutOpt, source: SourceOptions, channels: ChannelOptions,
    quiet: QuietOpt = False, as_json: WrittenJsonOpt = False,
) -> None:  # fmt: skip
    """Predict every sample of a data set (the time column named as in the file, + one column
    per output channel). One-step prediction uses earlier samples only; a simulation runs free
    over each record from its first --init-samples measured samples. --test-data replaces
    --data."""
    estimator, physics, series = _fitted(model, source, channels, quiet)
    frame = estimator.predict(series, physics)
    write_frame(frame, out)
    if as_json:
        print_json({"model": estimator.name, "task": estimator.task.kind, "out": str(out),
                    "rows": len(frame), "columns": list(frame.columns)})  # fmt: skip
    elif not quiet:
        console.print(f"wrote {len(frame)} predictions of {', '.join(estimator.channels_)} to "
                      f"{escape(str(out))}")  # fmt: skip


@app.command()
@with_group("channels", ChannelOptions)
@with_group("source", SourceOptions)
def evaluate(
    model: ModelFileOpt, source: SourceOptions, channels: ChannelOptions,
    train_fraction: FractionOpt = None, score_from: ScoreFromOpt = 0,
    free_run_from: FreeRunOpt = "test", quiet: QuietOpt = False, as_json: JsonOpt = False,
) -> None:  # fmt: skip
    """Score a model on the test part of --data (the chronological split it was fitted with)
    or on separate --test-data records (replacing --data): the paper's relative errors and
    honest metrics (RMSE, NRMSE, skill against persistence) per channel.

    On plant data (true speeds known), the accuracy limits too: the floor (the lowest RMSE any predictor of the measured value can reach
    in the task), the RMSE against the true speed beside the encoders' own error, and their
    ratio (below 1: the model is a better speed sensor than the encoder)."""
    from drafttwin.evaluation import protocol

    source.refuse_fraction_with_test_data(train_fraction)
    if free_run_from not in protocol.FREE_RUN_FROM:
        raise ConfigError(f"unknown free-run start {free_run_from!r}", where="--free-run-from",
                          fix=f"use one of {', '.join(protocol.FREE_RUN_FROM)}")  # fmt: skip
    estimator, physics, series = _fitted(model, source, channels, quiet)
    data, test = (None, series) if source.test_data is not None else (series, None)
    result = protocol.evaluate(estimator, data, test=test, train_fraction=train_fraction,
                               mechanistic=physics, skip_rows=score_from,
                               free_run_from=free_run_from)  # fmt: skip
    _report(result, as_json)


def _report(result: Evaluation, as_json: bool) -> None:
    if as_json:
        print_json(result.to_dict())
        return
    rows = result.split.get("test_rows")
    console.print(_metrics_table(result.metrics, f"{result.model} ({result.task}) on "
                                 f"{rows} test rows, {result.scored_rows} scored"))  # fmt: skip
    for name, m in result.metrics.items():
        if m.rel_note:
            console.print(f"{escape(name)}: {m.rel_note}")
    for line in _selection_lines(result.selection):
        console.print(line)
    console.print("skill = 1 - RMSE / RMSE(persistence); scored: measured samples not flagged "
                  "as outliers" + ("" if result.task == "prediction" else ", after each "
                                   "record's initialisation window"))  # fmt: skip
    if any(np.isfinite(m.sensor_rmse) for m in result.metrics.values()):
        console.print(_limits_table(result.metrics))
        console.print(FLOOR_NOTE[result.task == "prediction"])


FLOOR_NOTE = {
    True: "floor: the lowest RMSE any one-step predictor of the measured value can reach (an "
    "oracle that knows the true value and every earlier measurement; the encoders' counting "
    "error is partly foreseeable). sensor error: RMSE of measured vs true; vs true / sensor "
    "< 1: the prediction estimates the true value better than the encoder measures it",
    False: "floor: in a free run no measurement shows the sensor's error, so the floor is the "
    "sensor error (RMSE of measured vs true); vs true / sensor < 1: the simulation estimates "
    "the true value better than the encoder measures it",
}
"""The line under the table on data with true values, per task (one-step or free run)."""


def _shared_unit(metrics: dict[str, ChannelMetrics]) -> str | None:
    units = {m.unit for m in metrics.values()}
    return units.pop() if len(units) == 1 else None


def _limits_table(metrics: dict[str, ChannelMetrics]) -> Table:
    """The accuracy limits per channel, beside the RMSE they bound (data with true values)."""
    shared = _shared_unit(metrics)
    table = Table(title="accuracy limits (true values known)")
    table.add_column("channel")
    if shared is None:
        table.add_column("unit")
    unit = f" {shared}" if shared else ""
    for c in (f"RMSE{unit}", f"floor{unit}", "RMSE / floor", f"RMSE vs true{unit}",
              f"sensor error{unit}", "vs true / sensor"):  # fmt: skip
        table.add_column(c, justify="right")
    for r, m in metrics.items():
        over = m.rmse / m.rmse_floor if m.rmse_floor > 0 else float("nan")  # NaN: unknown
        cells = [f"{m.rmse:.4g}", f"{m.rmse_floor:.4g}", f"{over:.3f}",
                 f"{m.rmse_vs_true:.4g}", f"{m.sensor_rmse:.4g}", f"{m.true_error_ratio:.3f}"]  # fmt: skip
        table.add_row(escape(r), *([] if shared is not None else [m.unit]), *cells)
    return table


def _metrics_table(metrics: dict[str, ChannelMetrics], title: str) -> Table:
    """One row per channel; the unit in the headers when the channels share one, else in a
    column of its own."""
    shared = _shared_unit(metrics)

    def head(label: str) -> str:
        return f"{label} {shared}" if shared else label

    table = Table(title=escape(title))
    table.add_column("channel")
    if shared is None:
        table.add_column("unit")
    for c in ("max rel %", "mean rel %", "accuracy %", head("RMSE"), "NRMSE", "skill"):
        table.add_column(c, justify="right")
    for r, m in metrics.items():
        cells = [f"{m.max_rel_err_pct:.4f}", f"{m.mean_rel_err_pct:.4f}", f"{m.accuracy_pct:.3f}",
                 f"{m.rmse:.4g}", f"{m.nrmse:.3f}", f"{m.skill:.3f}"]  # fmt: skip
        table.add_row(escape(r), *([] if shared is not None else [m.unit]), *cells)
    return table
