"""``drafttwin fit``, ``predict`` and ``evaluate``: the models on measured data, any machine."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import numpy as np
import typer
from rich.markup import escape

from drafttwin.cli._common import write_frame
from drafttwin.cli._data import ChannelOptions
from drafttwin.cli._fitprint import fit_advice, report, selection_lines, tuning_lines
from drafttwin.cli._groups import stops_cleanly, with_group
from drafttwin.cli._modelopts import SetOpt, TuneOptions, parse_settings
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
from drafttwin.cli.typer_app import app, console, err_console, print_json
from drafttwin.errors import ConfigError, DataError

if TYPE_CHECKING:
    from drafttwin.cli._data import Channels
    from drafttwin.data.series import MeasurementSeries
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
@with_group("tune", TuneOptions)
@with_group("channels", ChannelOptions)
@with_group("source", SourceOptions)
def fit(
    model: ModelKindOpt, out: ModelOutOpt, source: SourceOptions, channels: ChannelOptions,
    tune: TuneOptions,
    profile: ProfileOpt = None, train_fraction: FractionOpt = None, seed: SeedOpt = None,
    horizon: HorizonOpt = 1, epochs: EpochsOpt = None, settings: SetOpt = None,
    full_model: FullModelOpt = False, quiet: QuietOpt = False, as_json: JsonOpt = False,
) -> None:  # fmt: skip
    """Fit a model and save it. Trains on the first --train-fraction of --data (preprocessed as
    in the paper; 'drafttwin evaluate' then scores the rest), or on all of --data when separate
    --test-data records are given: these are scored at once and the metrics printed.

    On a small record (hundreds to a few thousand rows) the profile's hyperparameters are a
    guess: --tune searches them on validation data within --tune-budget CPU-minutes, and is
    the thing to do."""
    from drafttwin.application import FitRequest, plan_physics, run_fit
    from drafttwin.cli._terms import CliTerms, typed

    parsed = channels.parse()
    request = FitRequest(
        model=model, mechanistic=source.mechanistic, profile=profile,
        settings=parse_settings(settings), task=source.task, init_samples=source.init_samples,
        horizon=None if horizon == 1 else horizon, inputs=parsed.inputs, seed=seed,
        epochs=epochs, train_fraction=train_fraction, full_model=full_model,
        tune=tune.tune, tune_budget=tune.tune_budget, tune_seed=tune.tune_seed, tune_trials=tune.tune_trials,
        tune_storage=tune.storage(out), data_label=source.fit_data, quiet=quiet,
    )  # fmt: skip
    given = request.given() | {"outputs", "inputs"}
    terms = CliTerms(given)
    with typed(given):
        _replaceable_model_file(out)
        tune.check(out)
        _, physics, _ = plan_physics(request, channels=parsed.outputs,
                                     time_column=parsed.time_column)  # fmt: skip
        needs = () if physics is None else physics.required_inputs()
        parsed = _with_nominal(parsed, physics)  # rad/s refused as evaluate refuses it
        series = parsed.read(source.fit_data, needs)
        test = None if source.test_data is None else parsed.read(source.test_data, needs)
        if physics is not None and parsed.check_units and parsed.nominal_rpm is None:
            _check_level(physics, series, source.fit_data)  # simulator files: cheap to read
        with tune.progress(quiet or as_json) as told, tune.stoppable():
            result = run_fit(request.replace(data=series, test=test), progress=told)
    if not quiet:
        for note in result.notes:
            err_console.print(f"note: {escape(note.render(terms))}", highlight=False,
                              soft_wrap=True)  # fmt: skip
    estimator, part = result.model, result.split
    estimator.save(out)
    pre = part.summary["preprocessing"]["train"]
    filled, smoothed = sum(pre["filled"].values()), sum(pre["outliers"].values())
    (err_console if as_json or quiet else console).print(  # --json: stdout holds the JSON
        f"fitted {estimator.name} ({estimator.task.kind}) on {part.summary['train_rows']} rows "
        f"in {part.summary['train_records']} record(s), channels {', '.join(estimator.channels_)} "
        f"({filled} samples filled, {smoothed} outliers smoothed); wrote {escape(str(out))}"
    )
    if not (quiet or as_json):
        for line in fit_advice(result):
            console.print(escape(line), highlight=False, soft_wrap=True)
    if result.evaluation is not None:  # separate test records: scored now (else: evaluate)
        report(result.evaluation, as_json)
        return
    if as_json:
        print_json({"model": estimator.name, "task": estimator.task.kind,
                    "selection": estimator.selection_, "split": part.summary,
                    "tuning": result.tuning})  # fmt: skip
        return
    for line in selection_lines(estimator.selection_):
        console.print(escape(line), highlight=False, soft_wrap=True)
    for line in tuning_lines(estimator.provenance_.get("tuning")):
        console.print(escape(line), highlight=False, soft_wrap=True)


def _fitted(
    model_file: Path, source: SourceOptions, channels: ChannelOptions, quiet: bool
) -> tuple[BaseModel, MechanisticModel | None, MeasurementSeries]:
    """A model file, its physics and the data of predict / evaluate, checked against it."""
    import warnings

    from drafttwin.application import resolve_physics
    from drafttwin.models import load_model
    from drafttwin.models.storage.modelfile import DeviceFallbackWarning

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
    physics = resolve_physics(source.mechanistic, estimator, parsed.outputs,
                              time_column=parsed.time_column)  # fmt: skip
    fitted_on = estimator.provenance_.get("data")
    spec = source.spec(fitted_on if isinstance(fitted_on, str) else None)
    if source.data is None and source.test_data is None and spec != "default" and not quiet:
        err_console.print(f"note: --data not given: the data {escape(model_file.name)} was "
                          f"fitted on, {escape(spec)}", highlight=False, soft_wrap=True)  # fmt: skip
    series = parsed.read(spec, () if physics is None else physics.required_inputs())
    _check_rate(estimator, series, spec)
    if physics is not None and parsed.check_units:
        _check_level(physics, series, spec)
    elif parsed.check_units:
        _check_trained(estimator, series, spec)
    return estimator, physics, series


def _check_trained(estimator: BaseModel, series: MeasurementSeries, spec: str) -> None:
    """A model without physics: each rpm channel's running level against the range it was
    trained on (a GRU fitted in rpm had been given a record in rad/s without a word)."""
    from drafttwin.data.units import check_units, is_rpm

    trained = estimator.output_range()
    rpm = [j for j, c in enumerate(series.channels) if is_rpm(series.unit(c)) and c in trained]
    if rpm:
        names = [series.channels[j] for j in rpm]
        check_units(series.values[:, rpm], names, spec,
                    trained_rpm={n: trained[n] for n in names})  # fmt: skip


def _with_nominal(parsed: Channels, physics: MechanisticModel | None) -> Channels:
    """The channels read with the drive train's rated speeds as the level a column in rad/s
    is told by (a fit on rad/s had written a model evaluate then refused); its kinematics
    only, no simulation."""
    from dataclasses import replace

    from drafttwin.cli._data import nominal_rpm

    train = None if physics is None else physics.train
    if train is None or not parsed.check_units or parsed.nominal_rpm is not None:
        return parsed
    return replace(parsed, nominal_rpm=nominal_rpm(train))


def _check_level(physics: MechanisticModel, series: MeasurementSeries, spec: str) -> None:
    """Each rpm channel's running level against its physics': a column in rad/s or rev/s is
    refused by name (a model in rpm had predicted 354.8 for a back roller recorded at 37.1)."""
    from drafttwin.data.units import check_units, is_rpm
    from drafttwin.errors import DrafttwinError

    rpm = [j for j, c in enumerate(series.channels) if is_rpm(series.unit(c))]
    if not rpm:
        return
    try:
        values = physics.predict_values(series)
    except DrafttwinError:
        return  # the prediction itself says what is wrong
    names = [series.channels[j] for j in rpm]
    with np.errstate(all="ignore"):
        nominal = {
            n: float(np.nanmedian(np.abs(values[:, j]))) for n, j in zip(names, rpm, strict=True)
        }
    check_units(series.values[:, rpm], names, spec,
                nominal_rpm={n: v for n, v in nominal.items() if np.isfinite(v) and v > 0})  # fmt: skip


@app.command()
@with_group("channels", ChannelOptions)
@with_group("source", SourceOptions)
@stops_cleanly("nothing was written")
def predict(
    model: ModelFileOpt, out: PredictionsOutOpt, source: SourceOptions, channels: ChannelOptions,
    quiet: QuietOpt = False, as_json: WrittenJsonOpt = False,
) -> None:  # fmt: skip
    """Predict every sample of a data set (the time column named as in the file, + one column
    per output channel). One-step prediction uses earlier samples only; a simulation runs free
    over each record from its first --init-samples measured samples. --test-data replaces
    --data."""
    estimator, physics, series = _fitted(model, source, channels, quiet)
    if physics is not None:
        physics.match_records(series)  # a simulator file of another record is refused
    frame = estimator.predict(series, physics)
    if len(frame) and frame[list(estimator.channels_)].isna().all().all():
        raise DataError(f"no prediction: every one of the data's {len(frame)} rows is the "
                        "model's history or its measured start",
                        source=source.spec(None), where="--data",
                        fix="give a longer record")  # fmt: skip
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
@stops_cleanly("nothing was written")
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
    if free_run_from != "test" and source.test_data is not None:
        raise ConfigError(f"--free-run-from {free_run_from} places the free run's start in a "
                          "chronological split, but --test-data is given",
                          where="--free-run-from",
                          fix="leave --free-run-from out: each test record runs free from its "
                          "own first --init-samples rows")  # fmt: skip
    if free_run_from not in protocol.FREE_RUN_FROM:
        raise ConfigError("unknown free-run start {free_run_from}",
                          terms={"free_run_from": free_run_from},
                          fix=f"use one of {', '.join(protocol.FREE_RUN_FROM)}")  # fmt: skip
    estimator, physics, series = _fitted(model, source, channels, quiet)
    _no_training_rows_scored(estimator, source, train_fraction)
    data, test = (None, series) if source.test_data is not None else (series, None)
    result = protocol.evaluate(estimator, data, test=test, train_fraction=train_fraction,
                               mechanistic=physics, skip_rows=score_from,
                               free_run_from=free_run_from)  # fmt: skip
    report(result, as_json)


def _replaceable_model_file(out: Path) -> None:
    """Refuse an ``--out`` that exists and is not a model file (a model file is a zip
    archive): a data file or a report given by mistake would be lost."""
    import zipfile

    if out.is_file() and out.stat().st_size > 0 and not zipfile.is_zipfile(out):
        raise ConfigError("exists and is not a model file, which --out would replace",
                          source=out, where="--out",
                          fix="name a new file (or a model file to replace)")  # fmt: skip


def _no_training_rows_scored(
    model: BaseModel, source: SourceOptions, train_fraction: float | None
) -> None:
    """Refuse a ``--train-fraction`` below the model's own on the data it was fitted on: the
    test part would hold rows the model trained on, and flatter it."""
    fitted = model.provenance_.get("train_fraction")
    fitted_on = model.provenance_.get("data")
    own = source.data is None or source.data == fitted_on
    if own and source.test_data is None and model.provenance_.get("split") == "records":
        # fitted on the whole of its records (its test was --test-data): a chronological
        # tail of them is training rows, scored as if unseen
        raise ConfigError(f"the model was fitted on all of {fitted_on}: a test part of it "
                          "would hold only rows the model trained on", where="--test-data",
                          fix="give --test-data with records it has not seen (or --data "
                          "another record)")  # fmt: skip
    if train_fraction is None or not fitted or not own or train_fraction >= fitted - 1e-12:
        return
    raise ConfigError(f"--train-fraction {train_fraction:g} is below the {fitted:g} the model was "
                      "fitted with: its test part would hold rows the model trained on",
                      where="--train-fraction",
                      fix=f"give {fitted:g} or more, or leave --train-fraction out")  # fmt: skip
