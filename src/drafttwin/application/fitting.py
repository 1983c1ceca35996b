"""One fit for the library and the command line: :func:`run_fit` takes a
:class:`~drafttwin.application.request.FitRequest`, builds the estimator, resolves the
physics, tunes when asked, splits, fits, scores separate test records and records the
provenance. ``dt.fit`` and ``drafttwin fit`` both call it, so they give the same numbers and
the same refusals."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from drafttwin.application.physics import resolve_physics
from drafttwin.application.request import FitNote, FitRequest, Note, build_model
from drafttwin.data.extremes import describe
from drafttwin.data.preprocessing import DEFAULT_TRAIN_FRACTION
from drafttwin.data.records import check_test_like_training
from drafttwin.errors import ConfigError
from drafttwin.evaluation import protocol
from drafttwin.models import BaseModel, MechanisticModel

if TYPE_CHECKING:
    from drafttwin.data.series import MeasurementSeries
    from drafttwin.evaluation.protocol import Evaluation, Split


@dataclass
class FitResult:
    """What a fit made: the fitted model, its split, the test records' scores (with
    ``test``), the physics it used, notes and, with ``tune``, the search."""

    model: BaseModel
    split: Split
    physics: MechanisticModel | None
    evaluation: Evaluation | None = None
    notes: list[Note] = field(default_factory=list)
    tuning: dict[str, Any] | None = None


def plan_physics(
    request: FitRequest, channels: Sequence[str] | None = None, time_column: str | None = None
) -> tuple[BaseModel, MechanisticModel | None, list[Note]]:
    """The estimator and the physics a request names, before any data are read (so a
    command can read the input channels the physics needs); ``channels`` and ``time_column``:
    the output channels and the time column's name the data will have (default: the
    request's data's)."""
    model, notes = build_model(request)
    if request.data is not None:
        channels = request.data.channels
        time_column = time_column or _file_time_column(request.data)
    physics = resolve_physics(request.mechanistic, model, channels, full_model=request.full_model,
                              time_column=time_column)  # fmt: skip
    if request.full_model and (
        physics is None or physics.spec()["kind"] not in ("preset", "train")
    ):
        what = "uses no physics" if physics is None else "takes its physics from files"
        notes.append(Note(f"{{full_model:name}} changes nothing: the {model.name} model {what}",
                          {"full_model": True}))  # fmt: skip
    return model, physics, notes


def _file_time_column(series: MeasurementSeries) -> str | None:
    """The time column's name in the file the series was read from (``time_ms`` where its
    values were converted to seconds), else the series' own."""
    columns = series.metadata.get("columns")
    named = [str(k) for k, v in columns.items() if v == "time"] if isinstance(columns, dict) else []
    return named[0] if named else series.metadata.get("time_column")


def run_fit(
    request: FitRequest, progress: Callable[[dict[str, Any]], None] | None = None
) -> FitResult:
    """Fit as ``request`` says (see the module doc); ``progress`` is told of each tuning
    trial as it ends."""
    data = request.data
    if data is None:
        raise ConfigError("no training data", param="data", fix="pass the training records")
    if request.test is not None and request.train_fraction is not None:
        raise ConfigError("{train_fraction} splits the data, but separate test records are given",
                          terms={"train_fraction": request.train_fraction, "test": None},
                          fix="with {test:name} every row of the data trains: leave "
                          "{train_fraction:name} out")  # fmt: skip
    model, physics, notes = plan_physics(request)
    fraction = (
        None if request.test is not None else (request.train_fraction or DEFAULT_TRAIN_FRACTION)
    )
    if request.test is not None:
        check_test_like_training(request.test, data)
    _free_run_starts(model, data)
    tuning = None
    if request.tune:
        from drafttwin.application.tuning import tune

        model, tuning = tune(request, model, physics, fraction, progress)
    part = protocol.fit_split(model, data, train_fraction=fraction, test=request.test,
                              mechanistic=physics)  # fmt: skip
    notes += _stretched_notes(part.summary["preprocessing"]["train"], data)
    notes += _slow_clock_notes(data)
    notes += _shifted_grid_notes(physics, data, request.test)
    if tuning is not None:
        notes += _few_folds_notes(tuning, model)
    if request.data_label is not None:
        model.provenance_["data"] = request.data_label
    if tuning is not None:
        model.provenance_["tuning"] = tuning
    evaluation = None
    if request.test is not None:
        evaluation = protocol.evaluate(model, part, mechanistic=physics)
    return FitResult(model, part, physics, evaluation, notes, tuning)


def _stretched_notes(report: dict[str, Any], data: MeasurementSeries) -> list[Note]:
    """A note per training channel whose range a few samples set (``range_stretched`` of the
    preprocessing report, :mod:`drafttwin.data.extremes`)."""
    return [Note(f"the training part's {describe(name, found, data.unit(name))}, a glitch the "
                 "one-sample spike rule leaves (a burst of wrong samples?), sets the range the "
                 "networks scale it by, and they learn it poorly; correct or cut that sample")
            for name, found in report.get("range_stretched", {}).items()]  # fmt: skip


def _slow_clock_notes(data: MeasurementSeries) -> list[Note]:
    """A note when the records step by a whole number of seconds (a clock in ms read as s)."""
    from drafttwin.data.validate import slow_clock_note

    note = slow_clock_note(data.sample_rate_hz)
    return [] if note is None else [Note(note)]


def _shifted_grid_notes(physics: MechanisticModel | None, data: MeasurementSeries,
                        test: MeasurementSeries | None) -> list[Note]:  # fmt: skip
    """A note per simulator table one step off its record's grid (accepted: see
    :meth:`~drafttwin.models.MechanisticModel.grid_shifts`)."""
    if physics is None:
        return []
    pairs = [(physics, data)]
    if test is not None:
        first, second = physics.split_records(data.n_records, test.n_records)
        pairs = [(first, data), (second, test)]
    shifts = [s for source, series in pairs for s in source.grid_shifts(series)]
    return [Note(f"{{mechanistic:name}} file {table} starts {abs(shift):g} s "
                 f"{'after' if shift > 0 else 'before'} its record {record}, one step: its "
                 "values are read at the record's times as stamped; if the simulator stamps "
                 "each step at its other end, shift its time column by that step",
                 {"mechanistic": physics.name})
            for table, record, shift in shifts]  # fmt: skip


def _free_run_starts(model: BaseModel, data: MeasurementSeries) -> None:
    """Refuse a simulation whose measured start is as long as every training record: its
    free run would never start, and nothing it learnt could be scored."""
    init = model.task.init_samples if model.task.simulation else None
    longest = max(b - a for a, b in data.record_bounds())
    if init is not None and init >= longest:
        raise ConfigError(f"{{init_samples}} measured rows start each free run, but the longest "
                          f"training record has {longest} rows: no free run would start",
                          terms={"init_samples": init},
                          fix=f"give {{init_samples:name}} fewer than {longest} rows")  # fmt: skip


FEW_FOLDS = 2
"""A search judged on this many held-out parts of the training records or fewer picks its
configuration on too little evidence to trust it unseen: on the own-machine tutorial's two
training records the search chose accumulated changes that won both folds by 30 % and lost to
the profile's default on the test record and on 12 more records (docs/models.md, "Tuning")."""


def _few_folds_notes(tuning: dict[str, Any], model: BaseModel) -> list[Note]:
    """A note when the search replaced the profile's setting on the word of
    :data:`FEW_FOLDS` validation parts or fewer (a GRU/LSTM's one tail, two records)."""
    first = next((t for t in tuning["trials"] if t["number"] == 0), None)
    if first is None or tuning["chosen"] == {k: v for k, v in first["params"].items()
                                             if k != "seed"}:  # fmt: skip
        return []
    folds = int(model.selection_.get("correction", {}).get("folds") or 1)
    if folds > FEW_FOLDS:
        return []
    parts = "its validation tail" if folds == 1 else f"{folds} held-out folds"
    return [
        Note(
            f"the search chose among {tuning['n_trials']} trials on {parts} alone: a "
            "setting that wins there can be the search's luck; compare it with the "
            "profile's default on records it has not seen ({test:name}), or give more "
            "training records (three or more make three folds)",
            {"test": None},
        )
    ]


def fit(
    model: str | BaseModel,
    data: MeasurementSeries,
    *,
    test: MeasurementSeries | None = None,
    mechanistic: object | None = None,
    train_fraction: float | None = None,
    profile: str | None = None,
    task: str | None = None,
    init_samples: int | None = None,
    horizon: int | None = None,
    inputs: tuple[str, ...] | list[str] | None = None,
    seed: int | None = None,
    epochs: int | None = None,
    full_model: bool = False,
    tune: bool = False,
    tune_budget: float | None = None,
    tune_seed: int | None = None,
    tune_trials: int | None = None,
    tune_storage: str | None = None,
    quiet: bool = True,
    **settings: Any,
) -> BaseModel:
    """Fit a model as ``drafttwin fit`` does and return it, fitted.

    ``model``: a registry name (built under ``profile`` with ``settings`` over its
    hyperparameters: ``window=30, hidden=64, ...``) or an unfitted estimator. The first
    ``train_fraction`` (default 0.7) of ``data`` trains, or all of it with separate ``test``
    records. ``mechanistic``: the physics (a source or its command-line text; default: the
    FA320A preset, reduced unless ``full_model``, for the roller channels). With ``tune``
    the hyperparameters are searched on validation data within ``tune_budget`` CPU-minutes
    first (:mod:`drafttwin.application.tuning`). What ``drafttwin fit`` prints as a note (a
    setting that changes nothing, a sample that stretches a channel's range) is raised as a
    :class:`~drafttwin.application.request.FitNote` warning. Use :func:`run_fit` for the
    split, the test scores and the notes as well."""
    from pathlib import Path

    request = FitRequest(
        model=model, data=data, test=test, mechanistic=mechanistic, profile=profile,
        settings=settings, task=task, init_samples=init_samples, horizon=horizon,
        inputs=None if inputs is None else tuple(inputs), seed=seed, epochs=epochs,
        train_fraction=train_fraction, full_model=full_model, tune=tune,
        tune_budget=tune_budget, tune_seed=tune_seed, tune_trials=tune_trials,
        tune_storage=None if tune_storage is None else Path(tune_storage), quiet=quiet,
    )  # fmt: skip
    result = run_fit(request)
    for note in result.notes:  # what drafttwin fit prints as "note: ..."
        warnings.warn(note.render(), FitNote, stacklevel=2)
    return result.model
