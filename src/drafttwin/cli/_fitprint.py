"""What ``fit`` and ``evaluate`` print: the scores per channel, the accuracy limits, the
options chosen on validation data (with their fold scores) and the tuning's trial table.
Every figure is printed with what it measures."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from rich.markup import escape
from rich.table import Table

from drafttwin.cli.typer_app import console, print_json
from drafttwin.models.estimators.accumulation import ONE_RECORD

if TYPE_CHECKING:
    from drafttwin.application import FitResult
    from drafttwin.evaluation.metrics import ChannelMetrics
    from drafttwin.evaluation.protocol import Evaluation

CANDIDATE = {"none": "physics alone", "held": "measured residual held",
             "offset": "measured offset held", "level": "residual level",
             "accumulate": "accumulated changes", "residual": "residual model"}  # fmt: skip
"""How the validation candidates of a hybrid read in the report."""

OFFSET_TEXT = ("the record's mean residual over its initialisation rows, held over its free run; "
               "no network")  # fmt: skip
"""What the ``offset`` correction is, as the report says it."""

SMALL_DATA_ROWS = 5000
"""Below this many training rows ``fit`` advises ``--tune``."""


def _num(v: object) -> str:
    return "-" if not isinstance(v, int | float) or not np.isfinite(v) else f"{v:.3g}"


def selection_lines(selection: dict[str, Any]) -> list[str]:
    """The options a hybrid chose on validation data, each score with what it measures."""
    lines: list[str] = []
    correction = selection.get("correction") or {}
    choice = selection.get("accumulate")
    if correction.get("folds"):
        return lines + _fold_lines(correction, choice)
    if choice:
        what = "accumulated changes" if choice["accumulate"] else "residual level"
        scores = ", ".join(f"{k} {v:.3g}" for k, v in choice.get("validation_nrmse", {}).items()
                           if v is not None)  # fmt: skip
        how = ("chosen on the validation tail (free-run NRMSE of the residual, RMSE / its std "
               f"over the training part: {scores})" if scores else "set")  # fmt: skip
        lines.append(f"residual model predicts the {what}: {how}")
    if correction:
        scores = ", ".join(f"{CANDIDATE.get(k, k)} {v:.3g}"
                           for k, v in correction.get("validation_nrmse", {}).items()
                           if v is not None)  # fmt: skip
        kept = correction["kept"]
        lines.append(
            ("no correction: the physics alone predicts (the residual model did not beat it"
             if kept == "none" else f"correction kept: {CANDIDATE.get(kept, kept)} ("
             + ("beats the physics alone" if correction["chosen_by"] == "validation"
                else "kept by --set fallback=false" if correction["chosen_by"] == "user"
                else "no validation part to test it on"))
            + (f"; NRMSE of the output on the validation tail, RMSE / std of the residual "
               f"there: {scores})" if scores else ")")
        )  # fmt: skip
    return lines


def _fold_lines(correction: dict[str, Any], choice: dict[str, Any] | None) -> list[str]:
    folds = correction["folds"]
    what = (
        "folds of whole training records"
        if correction.get("fold_by") == "record"
        else "blocked folds of the training rows"
    )
    lines = [f"validation on {folds} {what} (NRMSE of the output on each held-out fold = "
             "RMSE / std of the measured residual y - physics there; mean [per fold], lower is "
             "better):"]  # fmt: skip
    means = correction.get("validation_nrmse", {})
    for name, per_fold in correction.get("fold_nrmse", {}).items():
        mean = means.get(name)
        if mean is None:
            finite = [v for v in per_fold if v is not None]
            mean = float(np.mean(finite)) if finite else None
        cells = " ".join(_num(v) for v in per_fold)
        lines.append(f"  {CANDIDATE.get(name, name):<22} {_num(mean):>7}  [{cells}]")
    if choice and choice.get("chosen_by") == ONE_RECORD:
        lines.append("residual model predicts the residual level (one training record: its folds "
                     "are blocks of it, too short to judge accumulated changes, whose error grows "
                     "with the run)")  # fmt: skip
    elif choice and choice.get("chosen_by") != "user":
        what = "accumulated changes" if choice["accumulate"] else "residual level"
        lines.append(f"residual model predicts the {what} (of the two, the lower fold mean; "
                     "of those that win reliably, if any)")  # fmt: skip
    elif choice:
        lines.append("residual model predicts the " + ("accumulated changes" if choice["accumulate"]
                                                       else "residual level") + " (set)")  # fmt: skip
    kept, wins = correction["kept"], correction.get("wins")
    rival = ("the physics alone and the measured residual held"
             if "held" in correction.get("validation_nrmse", {}) else "the physics alone")  # fmt: skip
    if correction.get("chosen_by") == "user":
        lines.append(f"correction kept: {CANDIDATE.get(kept, kept)} (--set fallback=false: "
                     "kept untested)")  # fmt: skip
    elif isinstance(correction.get("corrected"), dict):
        lines += _channel_lines(correction, rival)
    elif kept == "offset":
        lines.append(f"correction kept: measured offset held (beats the physics alone on {wins} "
                     f"of {folds} folds and by more than 1 % on the mean, and the residual model "
                     f"on the mean): {OFFSET_TEXT}")  # fmt: skip
    elif kept == "none":
        lines.append(f"no correction: the physics alone predicts (the residual model beat "
                     f"{rival} on {wins} of {folds} folds; it is kept only when it wins every "
                     "fold and by more than 1 % on the mean)")  # fmt: skip
    else:
        lines.append(f"correction kept: {CANDIDATE.get(kept, kept)} (beats {rival} on "
                     f"{wins} of {folds} folds and by more than 1 % on the mean)")  # fmt: skip
    return lines


def _channel_lines(correction: dict[str, Any], rival: str) -> list[str]:
    """The verdict per output channel: the correction is kept on a channel only where it wins
    there on every fold and by more than 1 % on that channel's mean."""
    kept, folds = correction["kept"], correction["folds"]
    corrected: dict[str, bool] = correction["corrected"]
    wins: dict[str, int] = correction.get("channel_wins") or {}
    per_fold = correction.get("channel_fold_nrmse") or {}
    judged = [k for k in correction.get("validation_nrmse", {})
              if k not in ("none", "held", "offset")]  # fmt: skip
    offset: dict[str, bool] = correction.get("offset") or {}
    cand = judged[0] if judged else kept  # the candidate judged (kept, or refused everywhere)
    name = CANDIDATE.get(cand, cand)
    lines = [f"per output channel (mean fold NRMSE, physics alone -> {name}; folds on which it "
             f"beat {rival}); corrected only where it wins every fold and by more than 1 % on "
             "the channel's mean:"]  # fmt: skip
    for j, channel in enumerate(corrected):
        means = [_channel_mean(per_fold.get(k), j) for k in ("none", cand)]
        verdict = ("offset held" if offset.get(channel) else "corrected" if corrected[channel]
                   else "physics alone")  # fmt: skip
        lines.append(f"  {channel:<22} {_num(means[0]):>7} -> {_num(means[1]):<7} "
                     f"{wins.get(channel, '-')} of {folds}  {verdict}")  # fmt: skip
    if offset:
        lines.append(f"offset held: the measured offset ({OFFSET_TEXT}) where it wins every "
                     "fold against the physics alone and by more than 1 % on the channel's mean, "
                     "and scores below the residual model there")  # fmt: skip
    if kept == "none":
        lines.append("no correction: the physics alone predicts every channel")
    return lines


def _channel_mean(per_fold: list[list[float | None]] | None, j: int) -> float | None:
    if not per_fold:
        return None
    values = [float(v) for fold in per_fold if (v := fold[j]) is not None]
    return float(np.mean(values)) if values else None


def tuning_lines(tuning: dict[str, Any] | None, limit: int = 12) -> list[str]:
    """The tuning's summary and its best trials (``evaluate`` and ``fit --tune`` print it)."""
    if not tuning:
        return []
    trials = [t for t in tuning.get("trials", []) if t.get("score") is not None]
    lines = [
        f"tuning: {tuning['n_trials']} trials ({tuning.get('n_complete', len(trials))} complete) "
        f"in {tuning['cpu_s'] / 60:.1f} of {tuning['budget_min']:g} CPU-minutes, sampler "
        f"{tuning['sampler']} seed {tuning['seed']}; score = {tuning['measure']}",
        f"chosen: {_params_text(tuning['chosen'])} (mean score {_num(tuning['chosen_score'])} "
        f"over seeds {', '.join(str(s) for s in tuning.get('chosen_seeds', []))})",
    ]
    best = sorted(trials, key=lambda t: t["score"])[:limit]
    if best:
        lines.append(f"best {len(best)} trials (score, seed, hyperparameters):")
        lines += [f"  #{t['number']:<4} {_num(t['score']):>7}  seed {t['params'].get('seed', '-')}"
                  f"  {_params_text({k: v for k, v in t['params'].items() if k != 'seed'})}"
                  for t in best]  # fmt: skip
    return lines


def _params_text(params: dict[str, Any]) -> str:
    return ",".join(f"{k}={_num(v) if isinstance(v, float) else v}" for k, v in params.items())


def fit_advice(result: FitResult) -> list[str]:
    """A line that says ``--tune`` is the thing to do on small data (when not tuned)."""
    rows = int(result.split.summary.get("train_rows", 0))
    if result.tuning is not None or not result.model.trains_networks or rows >= SMALL_DATA_ROWS:
        return []
    return [f"note: {rows} training rows is small data: the profile's hyperparameters are a "
            "guess here; 'fit --tune' searches them on validation data (default budget "
            f"{_default_budget():g} CPU-minutes) and is the thing to do"]  # fmt: skip


def _default_budget() -> float:
    from drafttwin.application.tuning import DEFAULT_BUDGET_MIN

    return DEFAULT_BUDGET_MIN


def report(result: Evaluation, as_json: bool) -> None:
    if as_json:
        print_json(result.to_dict())
        return
    rows = result.split.get("test_rows")
    console.print(_metrics_table(result.metrics, f"{result.model} ({result.task}) on "
                                 f"{rows} test rows, {result.scored_rows} scored"))  # fmt: skip
    for name, m in result.metrics.items():
        if m.rel_note:
            console.print(f"{escape(name)}: {m.rel_note}")
    for line in selection_lines(result.selection):
        console.print(escape(line), highlight=False, soft_wrap=True)
    for line in tuning_lines(result.tuning):
        console.print(escape(line), highlight=False, soft_wrap=True)
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
