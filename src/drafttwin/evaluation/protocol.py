"""The evaluation protocol: split, preprocess, predict, score. One implementation, used by the
command line, ``drafttwin reproduce`` and the EMPS benchmark.

* **Split.** Chronological (the first ``train_fraction`` of the rows train, the rest test,
  the paper's 70 / 30) or by records (every row of the given data trains; separate test
  records are scored whole).
* **Training data** are preprocessed as in the paper: missing samples interpolated, one-sample
  outliers smoothed. Both may use the next sample, which is fine: all of it lies before the
  test part.
* **Test inputs** are cleaned causally: a spike is dropped using past samples only and the
  models hold the last value; gaps stay gaps. No prediction sees a future sample.
* **Scoring target**: the measured test samples that the paper's outlier rule does not flag;
  everything else is not scored. In a simulation the initialisation window of each test
  record (the measured start the free run may use) is not scored either.
* **Baseline**: persistence with the same task (the last measured value, or in a simulation
  the last value of the initialisation window, held), for the skill score.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np
import pandas as pd

from drafttwin.data.preprocessing import (
    DEFAULT_TRAIN_FRACTION,
    outlier_scales,
    preprocess,
    reject_spikes_causal,
)
from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import ConfigError, DataError
from drafttwin.evaluation.limits import floor_oracle
from drafttwin.evaluation.metrics import ChannelMetrics, channel_metrics
from drafttwin.models.estimators.base import BaseModel
from drafttwin.models.estimators.baselines import PersistenceModel
from drafttwin.models.mechanistic import MechanisticModel, as_mechanistic, record_names

OUTLIER_THRESHOLD = 0.10
"""The paper's outlier rule: a one-sample jump of more than 10 %."""


@dataclass(frozen=True)
class Split:
    """Training and test data prepared by the protocol.

    Attributes:
        train: the training series, preprocessed as in the paper.
        test: the test series as the models see it (spikes dropped causally), with the
            measured values kept for scoring in ``target``. Chronological split: the test
            rows continue the training record(s) on the same time axis.
        target: the scoring target on ``test``'s rows, ``(n_test, channels)``; ``NaN`` = not
            scored (missing or an outlier by the paper's rule).
        joined: chronological split only: the whole series as one-step prediction sees it,
            the preprocessed training rows as history followed by ``test`` (same records as
            the data); ``None`` otherwise.
        mode: ``"chronological"``, ``"records"`` (separate test records) or ``"all"`` (every
            row trains, no test part: ``test`` is ``None``).
        summary: counts for reports (rows, preprocessing, scored samples).
        stats: what causal cleaning took from the training data (:func:`cleaning_stats`).
    """

    train: MeasurementSeries | None
    test: MeasurementSeries | None
    target: np.ndarray
    joined: MeasurementSeries | None
    mode: str
    summary: dict[str, Any] = field(default_factory=dict)
    stats: dict[str, dict[str, float | None]] = field(default_factory=dict)

    def test_part(self) -> MeasurementSeries:
        """``test``; a ConfigError for a split without a test part (every row trained)."""
        if self.test is None:
            raise ConfigError(
                "the data were split with no test part: every row trained the model",
                param="train_fraction",
                terms={"train_fraction": 1, "test": None},
                fix="fit with {train_fraction:name} below 1, or give separate {test:name} records",
            )
        return self.test


def cleaning_stats(train: MeasurementSeries) -> dict[str, dict[str, float | None]]:
    """Per channel, what causal cleaning of test data needs from the training data: the
    outlier rule's scale (``None``: the relative rule) and a floor for the relative rule
    (half the typical magnitude: near standstill 10 % of the last value is nothing, and a
    start-up must not be taken for a run of spikes)."""
    scales = outlier_scales(train)
    typical = np.nanmedian(np.abs(train.values), axis=0) if len(train) else np.zeros(0)
    return {
        c: {"scale": scales[c], "floor": float(0.5 * np.nan_to_num(typical[j]))}
        for j, c in enumerate(train.channels)
    }


def split(
    data: MeasurementSeries,
    *,
    train_fraction: float | None = DEFAULT_TRAIN_FRACTION,
    test: MeasurementSeries | None = None,
    outlier_threshold: float = OUTLIER_THRESHOLD,
) -> Split:
    """Split ``data`` chronologically (``train_fraction``) or, with ``test``, train on all of
    ``data`` and test on the separate records ``test``."""
    if test is None:
        if train_fraction is None or not 0.0 < train_fraction < 1.0:
            raise ConfigError(
                "{train_fraction} leaves no test part",
                terms={"train_fraction": train_fraction, "test": None},
                fix=f"use a fraction below 1 (e.g. {DEFAULT_TRAIN_FRACTION}), or give separate "
                "{test:name} records",
            )
        train_rows = int(round(train_fraction * len(data)))
        if train_rows < 2 or len(data) - train_rows < 2:
            raise DataError(f"{len(data)} rows are too few to split at {train_fraction:g}",
                            fix="use a longer recording or a train fraction nearer 0.5")  # fmt: skip
        train_part, test_part, mode = (
            data.slice(0, train_rows),
            data.slice(train_rows),
            "chronological",
        )
    else:
        train_part, test_part, mode = data, test, "records"
    clean_train, train_report = preprocess(train_part, outlier_threshold=outlier_threshold)
    stats = cleaning_stats(train_part)
    flagged = None
    if mode == "chronological":  # the first test sample's earlier neighbour is a training one
        flagged = preprocess(data, outlier_threshold=outlier_threshold)[1].outliers[
            len(train_part) :
        ]
    part = test_split(test_part, stats, outlier_threshold=outlier_threshold, outliers=flagged)
    summary = {**part.summary, "mode": mode, "train_rows": len(train_part),
               "train_records": train_part.n_records}  # fmt: skip
    summary["preprocessing"] = {"train": train_report.to_dict(), **part.summary["preprocessing"]}
    joined = None
    if mode == "chronological":
        joined = data.with_values(np.vstack([clean_train.values, part.test_part().values]))
    return Split(clean_train, part.test, part.target, joined, mode, summary, stats)


def test_split(
    test: MeasurementSeries,
    stats: dict[str, dict[str, float | None]],
    *,
    outlier_threshold: float = OUTLIER_THRESHOLD,
    outliers: np.ndarray | None = None,
) -> Split:
    """Separate test records, cleaned causally with the training data's ``stats``
    (:func:`cleaning_stats`, as a fitted model records them); nothing trains. The scoring
    target leaves out missing samples and the paper's outliers (found in the test records,
    or given as ``outliers``)."""
    if set(stats) != set(test.channels):
        raise DataError(
            f"the test data have channels {list(test.channels)}, the training data {sorted(stats)}",
            fix="read both with the same --outputs",
        )
    test_inputs, rejected = clean_causally(test, stats, outlier_threshold)
    if outliers is None:
        outliers = preprocess(test, outlier_threshold=outlier_threshold)[1].outliers
    scored = np.isfinite(test.values) & ~outliers
    target = np.where(scored, test.values, np.nan)
    summary = {
        "mode": "records",
        "test_rows": len(test),
        "test_records": test.n_records,
        "rate_hz": test.sample_rate_hz,
        "preprocessing": {
            "test_spikes_rejected_causally": int(rejected.sum()),
            "test_scored_samples": int(scored.sum()),
            "test_samples": int(scored.size),
        },
    }
    return Split(None, test_inputs, target, None, "records", summary, stats)


def clean_causally(
    test: MeasurementSeries, stats: dict[str, dict[str, float | None]], threshold: float
) -> tuple[MeasurementSeries, np.ndarray]:
    """The test series with spikes dropped using past samples only; the rule's scales and
    floors come from the training data (the future is not known online)."""
    rows = [stats[c] for c in test.channels]
    scale = np.array([np.nan if r["scale"] is None else r["scale"] for r in rows], dtype=float)
    floor = np.array([r["floor"] or 0.0 for r in rows], dtype=float)
    values, rejected = reject_spikes_causal(test, threshold, scale=scale, floor=floor)
    return test.with_values(values), rejected


FREE_RUN_FROM = ("test", "start")
"""Where a simulation's free run starts after a chronological split: at the test part (from
its own first measured rows) or at the start of the record (the test part scored)."""


def model_input(
    model: BaseModel, data: Split, free_run_from: str = "test"
) -> tuple[MeasurementSeries, int]:
    """The series a model predicts on, and the row of it where the test part starts.

    One-step prediction after a chronological split sees the training rows as history (every
    prediction uses earlier rows only). A simulation runs free over the test records alone,
    from their own measured starts, or with ``free_run_from="start"`` over the whole record
    from its first measured rows (the published protocol of many benchmarks)."""
    if free_run_from not in FREE_RUN_FROM:
        raise ConfigError("unknown free-run start {free_run_from}",
                          terms={"free_run_from": free_run_from},
                          fix=f"use one of {', '.join(FREE_RUN_FROM)}")  # fmt: skip
    if free_run_from == "start" and not model.task.simulation:
        raise ConfigError("{free_run_from} applies to a simulation; the model predicts "
                          "one step ahead (it sees every earlier row anyway)",
                          terms={"free_run_from": free_run_from},
                          fix="leave {free_run_from:name} out")  # fmt: skip
    whole = not model.task.simulation or free_run_from == "start"
    if data.joined is not None and whole:
        return data.joined, len(data.joined) - len(data.test_part())
    return data.test_part(), 0


@dataclass(frozen=True)
class Evaluation:
    """What :func:`evaluate` measured: per-channel metrics and how they were obtained.

    Where the data carry the true values (plant data), the metrics hold the accuracy limits:
    ``rmse_vs_true`` (how close the twin is to the machine, not to its encoders) beside
    ``sensor_rmse`` (the encoders' own error), and ``rmse_floor`` (the lowest RMSE any
    predictor of the measured value can reach in the task; :mod:`drafttwin.evaluation.limits`).
    """

    model: str
    task: str
    metrics: dict[str, ChannelMetrics]
    predictions: pd.DataFrame
    scored_rows: int
    selection: dict[str, Any]
    split: dict[str, Any]
    tuning: dict[str, Any] | None = None

    def rows(self) -> dict[str, dict[str, Any]]:
        """Per channel, the metrics (JSON-safe)."""
        return {c: m.to_dict() for c, m in self.metrics.items()}

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe (no NaN): metrics per channel, the task, options chosen on data."""
        return {
            "model": self.model,
            "task": self.task,
            "channels": self.rows(),
            "selection": self.selection,
            "tuning": self.tuning,
            "scored_rows": self.scored_rows,
            "split": self.split,
        }

    def to_frame(self) -> pd.DataFrame:
        """One row per channel."""
        return pd.DataFrame([{"channel": c, **r} for c, r in self.rows().items()])


def prepare(
    model: BaseModel,
    data: MeasurementSeries | Split | None,
    test: MeasurementSeries | None,
    train_fraction: float | None,
) -> Split:
    """The split a fitted model is scored on: ``data`` split as when the model was fitted
    (its recorded train fraction unless given), or the separate ``test`` records cleaned with
    the statistics the model recorded of its training data."""
    if isinstance(data, Split):
        return data
    fitted = getattr(model, "provenance_", {}) or {}
    if test is not None and data is None:
        stats = fitted.get("cleaning")
        if not stats:
            raise ConfigError(
                "the model file does not record its training data's statistics",
                fix="pass the training data too (data=... / --data), or re-fit the model",
            )
        return test_split(test, stats)
    if data is None:
        raise ConfigError("nothing to evaluate on", fix="pass data= and/or test=")
    if train_fraction is None and test is None:
        train_fraction = fitted.get("train_fraction") or DEFAULT_TRAIN_FRACTION
    return split(data, train_fraction=train_fraction, test=test)


def evaluate(
    model: BaseModel,
    data: MeasurementSeries | Split | None = None,
    *,
    test: MeasurementSeries | None = None,
    train_fraction: float | None = None,
    mechanistic: object | None = None,
    skip_rows: int = 0,
    free_run_from: str = "test",
) -> Evaluation:
    """Score a fitted model on the test part of ``data`` (chronological split, by default at
    the fraction the model was fitted with) or on the separate ``test`` records: the paper's
    relative errors and RMSE, NRMSE, skill against persistence, and where the data carry the
    true values the error against them, the sensor's own error and the task's floor. ``skip_rows``: rows at the start
    of each test record left unscored (so that models with different warm-ups are scored on
    the same rows; the CLI's ``--score-from``). ``free_run_from``: see :func:`model_input`."""
    part = prepare(model, data, test, train_fraction)
    if mechanistic is not None:  # text, a drive train or a callable: matched to records below
        mechanistic = as_mechanistic(mechanistic)
    mechanistic = _test_physics(mechanistic, part, data)
    series, first = model_input(model, part, free_run_from)
    mechanistic = _tables_of(mechanistic, part, series)
    pred = model.predict_values(series, mechanistic)[first:]
    return score(part, pred, model, skip_rows=skip_rows, free_run_from=free_run_from)


def _nothing_to_score(test: MeasurementSeries, model: BaseModel, skip_rows: int) -> None:
    """Refuse a score of no row: a table of NaN would read as a result."""
    longest = max(b - a for a, b in test.record_bounds())
    init = model._init_rows() if model.task.simulation else 0
    terms: dict[str, object] = {"skip_rows": skip_rows}
    used = []
    if init:
        terms["init_samples"] = init
        used.append("{init_samples} measured rows start the free run")
    if skip_rows:
        used.append("{skip_rows} rows are left unscored")
    why = " and ".join(used) or "no measured value is left in them"
    raise DataError(f"no test row is left to score: the longest test record has {longest} rows, "
                    f"and {why}", terms=terms,
                    fix="score longer test records, or start the scoring earlier")  # fmt: skip


def score(
    part: Split, pred: np.ndarray, model: BaseModel, *, skip_rows: int = 0,
    free_run_from: str = "test",
) -> Evaluation:  # fmt: skip
    """Score predictions ``pred`` of ``part``'s test rows made by ``model`` (its task sets the
    persistence baseline and, in a simulation, the unscored initialisation rows)."""
    series, first = model_input(model, part, free_run_from)
    test = part.test_part()
    baseline = PersistenceModel(task=model.task.replace(inputs=()))
    baseline.fit(test)
    pers = baseline.predict_values(series)[first:]
    target = part.target.copy()
    if model.task.simulation:  # a free run's measured start is no prediction
        measured = np.zeros(len(series), bool)
        for a, b in series.record_bounds():
            measured[a : min(b, a + model._init_rows())] = True
        target[measured[first:]] = np.nan
    for a, b in test.record_bounds():
        target[a : min(b, a + skip_rows)] = np.nan
    if target.size and not np.isfinite(target).any():
        _nothing_to_score(test, model, skip_rows)
    units = {c: test.unit(c) for c in test.channels}
    truth = test.truth
    metrics = channel_metrics(target, pred, channels=test.channels, units=units,
                             persistence=pers, true_values=truth,
                             floor_values=_oracle(part, model, truth))  # fmt: skip
    frame = pd.DataFrame({test.time_column: test.time_s})
    for j, name in enumerate(test.channels):
        frame[name] = pred[:, j]
    if test.n_records > 1:
        frame["record"] = test.record_ids()
    frame.attrs["units"] = units
    return Evaluation(
        model=model.name,
        task=model.task.kind,
        metrics=metrics,
        predictions=frame,
        # a row counts where a channel has both a measurement and a prediction (a separate
        # test record's first window has no prediction)
        scored_rows=int((np.isfinite(target) & np.isfinite(pred)).any(axis=1).sum()),
        selection=dict(getattr(model, "selection_", {})),
        tuning=(getattr(model, "provenance_", {}) or {}).get("tuning"),
        split={**part.summary, "score_from": skip_rows,
               **({"free_run_from": free_run_from} if model.task.simulation else {})},
    )  # fmt: skip


def _test_physics(
    mechanistic: object | None, part: Split, data: MeasurementSeries | Split | None
) -> object | None:
    """The physics of the records scored, checked against them: from simulator files for the
    training records then the test records (as :func:`fit` was given them), the test
    records' ones; files for the whole records of a chronological split are matched with
    those records (``data``)."""
    if not isinstance(mechanistic, MechanisticModel):
        return mechanistic
    if part.mode == "records":
        test = part.test_part()
        train_records = part.summary.get("train_records")
        if train_records and mechanistic.n_tables == int(train_records) + test.n_records:
            mechanistic = mechanistic.split_records(int(train_records), test.n_records)[1]
        mechanistic.match_records(test)
    elif isinstance(data, MeasurementSeries):
        mechanistic.match_records(data)
    return mechanistic


def _tables_of(mechanistic: object | None, part: Split, series: MeasurementSeries) -> object | None:
    """The simulator tables of the records ``series`` holds: after a chronological split a
    simulation runs free over the test part alone, the last of the whole data's records (the
    first of them its tail), whose tables are the last ones given."""
    if not isinstance(mechanistic, MechanisticModel) or part.joined is None:
        return mechanistic
    n_whole, n_here = part.joined.n_records, series.n_records
    if mechanistic.n_tables == n_whole and n_here < n_whole:
        return mechanistic.split_records(n_whole - n_here, n_here)[1]
    return mechanistic


def _oracle(part: Split, model: BaseModel, truth: np.ndarray | None) -> np.ndarray | None:
    """The floor oracle's predictions of the test rows (None without true values): it knows
    the true values and, in one-step prediction, every earlier scored measurement. A free run
    sees no measurement, and a prediction ``horizon`` >= 2 rows ahead sees only errors that
    share no window boundary with the predicted one: nothing of the sensor's error can be
    foreseen, so the floor is the sensor's own error."""
    if truth is None:
        return None
    test = part.test_part()
    blind = model.task.simulation or model.task.horizon > 1
    observed = np.zeros(truth.shape, bool) if blind else None
    starts = [a for a, _ in test.record_bounds()]
    return floor_oracle(part.target, truth, observed=observed, record_starts=starts)


Model = TypeVar("Model", bound=BaseModel)


def fit(
    model: Model,
    data: MeasurementSeries | Split,
    *,
    train_fraction: float | None = DEFAULT_TRAIN_FRACTION,
    test: MeasurementSeries | None = None,
    mechanistic: object | None = None,
) -> Model:
    """Fit ``model`` as :func:`fit_split` does and return it, fitted (as scikit-learn's
    ``fit``); :func:`fit_split` returns the split instead, for :func:`evaluate`."""
    fit_split(model, data, train_fraction=train_fraction, test=test, mechanistic=mechanistic)
    return model


def split_for_fit(
    data: MeasurementSeries,
    train_fraction: float | None = DEFAULT_TRAIN_FRACTION,
    test: MeasurementSeries | None = None,
) -> Split:
    """The split :func:`fit_split` trains on: chronological at ``train_fraction``, all of
    ``data`` with ``train_fraction=1`` or with separate ``test`` records."""
    if test is None and train_fraction is not None and train_fraction >= 1.0:
        clean, report = preprocess(data)
        summary = {"mode": "all", "train_rows": len(data), "train_records": data.n_records,
                   "preprocessing": {"train": report.to_dict()}}  # fmt: skip
        return Split(clean, None, np.zeros((0, len(data.channels))), None, "all", summary,
                     cleaning_stats(data))  # fmt: skip
    return split(data, train_fraction=train_fraction, test=test)


def fit_split(
    model: BaseModel,
    data: MeasurementSeries | Split,
    *,
    train_fraction: float | None = DEFAULT_TRAIN_FRACTION,
    test: MeasurementSeries | None = None,
    mechanistic: object | None = None,
) -> Split:
    """Fit ``model`` on the protocol's training part of ``data`` (the first
    ``train_fraction``; all of it with ``train_fraction=1`` or when separate ``test`` records
    are given) and record how in ``model.provenance_``; returns the split, so the same test
    part can be scored with :func:`evaluate` (``split.test`` is ``None`` without a test part).
    """
    part = data if isinstance(data, Split) else split_for_fit(data, train_fraction, test)
    assert part.train is not None
    if isinstance(mechanistic, MechanisticModel) and not isinstance(data, Split):
        for_test = None
        if test is not None:  # simulator files for the training records, then the test ones
            names = record_names(data) + record_names(test)
            mechanistic, for_test = mechanistic.split_records(data.n_records, test.n_records, names)
        mechanistic.match_records(data)  # whole records, before the split
        if for_test is not None and test is not None:
            for_test.match_records(test)
    model.fit(part.train, mechanistic)
    model.provenance_.update({
        "split": part.mode,
        "train_fraction": train_fraction if part.mode != "records" else None,
        "train_rows": len(part.train),
        "train_records": part.train.n_records,
        "cleaning": part.stats,
    })  # fmt: skip
    return part
