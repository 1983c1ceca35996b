"""Tuning as part of fitting: ``fit --tune`` searches the hyperparameters that matter on
validation data of the training records only, within a CPU budget.

The search is Optuna's (the optional extra ``tune``): a seeded TPE sampler (the same
``tune_seed`` gives the same trials in the same order) over the windows, hidden sizes,
layers, dropout, learning rate and its schedule, batch size, epochs and patience, and a hybrid's structure
(and MD-S-L's data-driven model and SKNet width); what the caller set stays fixed. Trial 0 is
the profile's own setting, so the search never ends below it on validation. A trial fits the
model on the training part and scores it on validation data: a hybrid by the blocked folds of
its training records (:mod:`drafttwin.models.estimators.folds`: the mean NRMSE of the output on the
held-out blocks of what it keeps: per output channel the correction or its physics alone), a GRU/LSTM
by its validation tail. Once :data:`SEED_PHASE` of the budget is spent, the best
:data:`TOP_CONFIGS` configurations are run again with other network seeds, and the
configuration with the best mean over :data:`SEEDS` seeds is chosen (one seed is not a
result: their spread is large on small data), fitted with its best seed.

The budget is CPU time (user + system) of this process, in minutes, its start-up and data
reading included; the search stops when the next trial (its cost estimated by the mean so
far) and the final fit (at worst the costliest trial so far) would not fit in it.
The trials go to a journal file (``tune_storage``): a second run with the same request and
file resumes the search where it stopped, with what it had spent. The trial table is kept in
the fitted model's provenance (``provenance_["tuning"]``, in its file) and ``evaluate``
prints it."""

from __future__ import annotations

import hashlib
import json
import math
import resource
from collections.abc import Callable, Generator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from drafttwin.application.request import FitRequest, build_model
from drafttwin.errors import ConfigError, DrafttwinError
from drafttwin.evaluation import protocol
from drafttwin.execution.interrupt import Interrupted, signals_deferred
from drafttwin.models import BaseModel, MechanisticModel

if TYPE_CHECKING:
    import optuna

DEFAULT_BUDGET_MIN = 10.0
"""CPU-minutes of a search when none is given: on a 500-1000-row record it beats the
profile's defaults (docs/models.md, "Tuning")."""
SEEDS = 3
"""Network seeds each of the best configurations is scored with."""
TOP_CONFIGS = 2
"""Configurations run again with the other seeds."""
SEED_PHASE = 0.6
"""Share of the budget after which the best configurations get their other seeds."""
MEASURE = (
    "validation score: a hybrid's mean NRMSE of the output on blocked folds of the training "
    "records (what it keeps; its physics alone scores 1 or more), a GRU/LSTM's RMSE on its "
    "validation tail (scaled units)"
)

Progress = Callable[[dict[str, Any]], None]


def cpu_seconds() -> float:
    """User + system CPU time of this process and its finished children, s."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def validation_score(model: BaseModel) -> float:
    """The fitted ``model``'s score on validation data of its training records (lower is
    better; see the module doc)."""
    correction = getattr(model, "selection_", {}).get("correction") or {}
    folds = correction.get("fold_nrmse")
    if folds:
        chosen = correction.get("chosen_fold_nrmse") or folds.get(correction["kept"], [])
        values = [v for v in chosen if v is not None]
        return float(np.mean(values)) if values else math.inf
    history = getattr(model, "history_", None)
    if history is not None and history.val_loss:
        return float(math.sqrt(min(history.val_loss)))
    raise ConfigError(f"the {model.name} model gives no validation score to tune on",
                      param="tune", terms={"tune": True},
                      fix="tune a model that trains networks with a validation part")  # fmt: skip


def _choices(values: list[Any], keep: Any) -> list[Any]:
    return sorted(set(values) | {keep}, key=lambda v: (v is None, v))


def search_space(model: BaseModel, fixed: set[str]) -> dict[str, list[Any] | tuple[float, float]]:
    """The hyperparameters searched for ``model`` (a list: categorical; a pair: log-uniform),
    each including the model's own value; ``fixed`` (set by the caller) are left out."""
    params = model.get_params(deep=False)
    training = params.get("training")
    init = model.task.init_samples if model.task.simulation else None
    windows = [w for w in (5, 10, 20, 30, 50) if init is None or w <= init]
    space: dict[str, list[Any] | tuple[float, float]] = {
        "window": _choices(windows, params["window"]),
        "hidden": _choices([16, 32, 64, 128], params["hidden"]),
        "layers": _choices([1, 2, 3], params["layers"]),
        "dropout": _choices([0.0, 0.1, 0.2], params["dropout"]),
    }
    if training is not None:
        space |= {"lr": (3e-4, 1e-2),
                  "batch_size": _choices([16, 32, 64], training.batch_size),
                  "epochs": _choices([30, 80, 150, 300], training.epochs),
                  "patience": _choices([5, 15, 30], training.patience),
                  "schedule": _choices(["constant", "cosine"], training.schedule)}  # fmt: skip
    if "structure" in params:
        space["structure"] = ["absolute", "relative"]
    data_model = params.get("data_model")
    if data_model is not None:
        dm = data_model.get_params(deep=False)
        space |= {"data_window": _choices(windows, dm["window"]),
                  "data_hidden": _choices([16, 32, 64, 128], dm["hidden"]),
                  "data_layers": _choices([1, 2], dm["layers"]),
                  "sk_channels": _choices([12, 24, 48], params["sk_channels"])}  # fmt: skip
    return {k: v for k, v in space.items() if k not in fixed}


def _own_values(model: BaseModel, names: list[str]) -> dict[str, Any]:
    """The model's own values of the searched names (trial 0: the profile's setting)."""
    params = model.get_params(deep=False)
    flat = dict(params)
    if params.get("training") is not None:
        flat |= params["training"].to_dict()
    if params.get("data_model") is not None:
        dm = params["data_model"].get_params(deep=False)
        flat |= {f"data_{k}": dm[k] for k in ("window", "hidden", "layers")}
    return {k: flat[k] for k in names}


def _fingerprint(
    request: FitRequest, physics: MechanisticModel | None, fraction: float | None
) -> str:
    """What makes two searches the same one (a journal resumes only its own)."""
    digest = hashlib.sha256()
    for series in (request.data, request.test):
        if series is not None:
            digest.update(np.ascontiguousarray(series.values).tobytes())
            digest.update(np.ascontiguousarray(series.time_s).tobytes())
    spec = {k: v for k, v in (physics.spec() if physics else {}).items() if k != "spec"}
    key = {"model": request.model_name, "profile": request.profile, "task": request.task,
           "init": request.init_samples, "horizon": request.horizon, "inputs": request.inputs,
           "settings": {k: repr(v) for k, v in sorted(request.settings.items())},
           "seed": request.seed, "epochs": request.epochs, "fraction": fraction,
           "physics": repr(spec), "tune_seed": request.tune_seed or 0}  # fmt: skip
    digest.update(json.dumps(key, sort_keys=True).encode())
    return digest.hexdigest()[:16]


def _suggest(
    trial: optuna.Trial, space: dict[str, list[Any] | tuple[float, float]]
) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, choice in space.items():
        if isinstance(choice, tuple):
            out[name] = trial.suggest_float(name, choice[0], choice[1], log=True)
        else:
            out[name] = trial.suggest_categorical(name, choice)
    return out


def tune(
    request: FitRequest,
    model: BaseModel,
    physics: MechanisticModel | None,
    fraction: float | None,
    progress: Progress | None = None,
) -> tuple[BaseModel, dict[str, Any]]:
    """Search ``request``'s model's hyperparameters (see the module doc); returns the model
    of the chosen configuration and seed, unfitted, and the search's record."""
    if not model.trains_networks:
        raise ConfigError(f"the {model.name} model trains nothing to tune", param="tune",
                          terms={"tune": True}, fix="leave {tune:name} out")  # fmt: skip
    optuna = _optuna()
    assert request.data is not None
    budget_min = request.tune_budget or DEFAULT_BUDGET_MIN
    part = protocol.split_for_fit(request.data, train_fraction=fraction, test=request.test)
    assert part.train is not None
    train = part.train
    if physics is not None and request.test is not None:
        physics = physics.split_records(request.data.n_records, request.test.n_records)[0]
    fixed = set(request.settings) | ({"epochs"} if request.epochs is not None else set())
    space = search_space(model, fixed)
    base_seed = request.seed or 0
    seed = request.tune_seed or 0
    journal = request.tune_storage
    created = journal is not None and not journal.exists()
    storage = _storage(optuna, journal)
    name = f"drafttwin-{_fingerprint(request, physics, fraction)}"
    study = optuna.create_study(study_name=name, storage=storage, sampler=_sampler(optuna, seed, 0),
                                direction="minimize", load_if_exists=True)  # fmt: skip
    if not study.trials:
        study.enqueue_trial(_own_values(model, list(space)), user_attrs={"seed": base_seed})
    errors: list[DrafttwinError] = []

    mine: list[float] = []  # this process's trials (a resumed journal holds earlier ones)

    def spent() -> float:
        """The journal's trials, and this process's CPU outside its trials (start-up,
        reading the data, the sampler)."""
        trials = sum(float(t.user_attrs.get("cpu_s", 0.0))
                     for t in study.get_trials(deepcopy=False))  # fmt: skip
        return trials + max(0.0, cpu_seconds() - sum(mine))

    def run(params: dict[str, Any], net_seed: int) -> tuple[float | None, float]:
        trial_request = _with(request, params, net_seed).replace(quiet=True)
        start = cpu_seconds()
        try:
            candidate, _ = build_model(trial_request)
            candidate.fit(train, physics)
            score: float | None = validation_score(candidate)
        except Interrupted:  # a stop signal: the journal keeps the finished trials
            raise
        except DrafttwinError as exc:  # a setting these data cannot take: the trial fails
            errors.append(exc)
            score = None
        mine.append(cpu_seconds() - start)
        return score, mine[-1]

    while True:
        # a trial a stop cut short is still running in the journal: it runs again first, so
        # that the search goes on as an uninterrupted one would (same trials, same order)
        cut = study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.RUNNING,))
        if cut:
            trial = optuna.trial.Trial(study, cut[0]._trial_id)  # no public way to reopen one
            # its parameters as stored (a journal of an older version may lack some: drawn)
            study.sampler = _sampler(optuna, seed, cut[0].number)
            with signals_deferred():
                params = _suggest(trial, space)
            before = float(cut[0].user_attrs.get("cpu_s", 0.0))
        else:
            used = spent()
            if _stop(study, used, budget_min, request.tune_trials):
                break
            if _seed_phase(study, used, budget_min, request.tune_trials):
                _enqueue_seeds(study, base_seed)
            # seeded per trial: a resumed search draws what an uninterrupted one would
            study.sampler = _sampler(optuna, seed, len(study.trials))
            # a trial's parameters all in the journal or none: a stop between two had left a
            # trial that ran again with the rest at the profile's values
            with signals_deferred():
                trial = study.ask()
                params, before = _suggest(trial, space), 0.0
        net_seed = int(trial.user_attrs.get("seed", base_seed))
        trial.set_user_attr("seed", net_seed)
        start = cpu_seconds()
        try:
            score, cost = run(params, net_seed)
        except Interrupted:  # its CPU counts against the budget; it stays open in the journal
            trial.set_user_attr("cpu_s", before + cpu_seconds() - start)
            raise
        cost += before
        trial.set_user_attr("cpu_s", cost)
        if score is None or not math.isfinite(score):
            study.tell(trial, state=optuna.trial.TrialState.FAIL)
        else:
            study.tell(trial, score)
        if progress is not None:
            best = min((t.value for t in study.trials if t.value is not None), default=None)
            progress({"number": trial.number, "score": score, "best": best, "cpu_s": spent(),
                      "budget_min": budget_min, "params": _text(params, net_seed)})  # fmt: skip
    try:
        return _choose(study, request, model, space, errors, budget_min, seed, name, spent())
    except DrafttwinError:
        if created and journal is not None and not _complete(study):
            journal.unlink(missing_ok=True)  # a journal of nothing, in a file the user did not name
        raise


def _complete(study: optuna.Study) -> list[optuna.trial.FrozenTrial]:
    import optuna

    return [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]


def _ran(study: optuna.Study) -> int:
    import optuna

    return sum(1 for t in study.trials if t.state != optuna.trial.TrialState.WAITING)


def _stop(study: optuna.Study, used: float, budget_min: float, max_trials: int | None) -> bool:
    """Whether the search ends here: the next trial (the mean so far) and the final fit (at
    worst the costliest so far) would not fit in the budget, or the trials are all run."""
    costs = [float(t.user_attrs.get("cpu_s", 0.0)) for t in _complete(study)]
    need = float(np.mean(costs) + np.max(costs)) if costs else 0.0
    return used + need > budget_min * 60 or (max_trials is not None
                                              and _ran(study) >= max_trials)  # fmt: skip


def _seed_phase(
    study: optuna.Study, used: float, budget_min: float, max_trials: int | None
) -> bool:
    """Whether the best configurations get their other seeds now (:data:`SEED_PHASE`)."""
    return used >= SEED_PHASE * budget_min * 60 or (
        max_trials is not None and _ran(study) >= SEED_PHASE * max_trials
    )


def _sampler(optuna: Any, seed: int, n: int) -> Any:
    """TPE seeded by the search's seed and the trial's number (8 random trials first)."""
    return optuna.samplers.TPESampler(seed=(seed * 1_000_003 + n) % 2**32, n_startup_trials=8)


def _with(request: FitRequest, params: dict[str, Any], seed: int) -> FitRequest:
    """``request`` with a trial's hyperparameters (``epochs`` is a field of its own)."""
    settings = {k: v for k, v in params.items() if k != "epochs"}
    epochs = params.get("epochs", request.epochs)
    return request.replace(settings={**request.settings, **settings}, epochs=epochs, seed=seed,
                           tune=False)  # fmt: skip


def _text(params: dict[str, Any], seed: int) -> str:
    return ",".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}"
                    for k, v in {**params, "seed": seed}.items())  # fmt: skip


def _key(params: dict[str, Any]) -> str:
    return json.dumps(params, sort_keys=True, default=str)


def _enqueue_seeds(study: optuna.Study, base_seed: int) -> None:
    """Enqueue the other seeds of the best configurations (once each)."""
    import optuna

    trials = study.get_trials(deepcopy=False)
    if any(t.user_attrs.get("phase") == 2 for t in trials):
        return
    best: dict[str, tuple[float, dict[str, Any]]] = {}
    for t in trials:
        if t.state == optuna.trial.TrialState.COMPLETE and t.value is not None:
            key = _key(t.params)
            if key not in best or t.value < best[key][0]:
                best[key] = (t.value, t.params)
    for _, params in sorted(best.values(), key=lambda v: v[0])[:TOP_CONFIGS]:
        for k in range(1, SEEDS):
            study.enqueue_trial(params, user_attrs={"seed": base_seed + k, "phase": 2})


def _choose(
    study: optuna.Study, request: FitRequest, model: BaseModel,
    space: dict[str, Any], errors: list[DrafttwinError], budget_min: float, seed: int,
    name: str, cpu_s: float,
) -> tuple[BaseModel, dict[str, Any]]:  # fmt: skip
    """The configuration with the best mean score over its seeds (more seeds first), fitted
    with its best seed; and the search's record (the trial table)."""
    import optuna

    done = _complete(study)
    if not done:
        if errors:
            raise errors[0]
        raise ConfigError(
            f"the tuning budget of {budget_min:g} CPU-minutes ended before one trial ran",
            terms={"tune_budget": budget_min}, fix="give a larger {tune_budget:name}",
        )  # fmt: skip
    groups: dict[str, list[optuna.trial.FrozenTrial]] = {}
    for t in done:
        groups.setdefault(_key(t.params), []).append(t)
    seeds_max = max(len(g) for g in groups.values())

    def rank(g: list[optuna.trial.FrozenTrial]) -> tuple[int, float]:
        return (-min(len(g), seeds_max), float(np.mean([t.value for t in g])))

    chosen = min(groups.values(), key=rank)
    best = min(chosen, key=lambda t: t.value if t.value is not None else math.inf)
    net_seed = int(best.user_attrs.get("seed", request.seed or 0))
    final, _ = build_model(_with(request, best.params, net_seed))
    table = [{"number": t.number, "state": t.state.name.lower(), "score": t.value,
              "cpu_s": round(float(t.user_attrs.get("cpu_s", 0.0)), 2),
              "params": {**t.params, "seed": int(t.user_attrs.get("seed", 0))}}
             for t in study.trials if t.state != optuna.trial.TrialState.WAITING]  # fmt: skip
    record = {
        "library": f"optuna {optuna.__version__}", "sampler": "TPE", "seed": seed,
        "study": name, "budget_min": budget_min, "cpu_s": round(cpu_s, 1),
        "measure": MEASURE, "searched": sorted(space), "n_trials": len(table),
        "n_complete": len(done), "chosen": dict(best.params), "chosen_seed": net_seed,
        "chosen_seeds": sorted(int(t.user_attrs.get("seed", 0)) for t in chosen),
        "chosen_score": float(np.mean([t.value for t in chosen])),
        "default_score": next((t.value for t in study.trials if t.number == 0), None),
        "trials": table,
    }  # fmt: skip
    del model
    return final, record


def _optuna() -> Any:
    try:
        import optuna
    except ImportError:
        raise ConfigError("tuning needs Optuna, which is not installed", param="tune",
                          terms={"tune": True},
                          fix="pip install 'drafttwin[tune]' (or pip install optuna)") from None  # fmt: skip
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    return optuna


def _storage(optuna: Any, path: Path | None) -> Any:
    """A journal file (resumable), or memory when no file is given."""
    if path is None:
        return optuna.storages.InMemoryStorage()
    from optuna.storages.journal import JournalFileBackend

    class SignalSafeJournal(JournalFileBackend):
        """The journal with a stop signal held off while it reads or appends: raised inside
        Optuna's lock it would leave the lock file behind (or fail its release with a
        FileNotFoundError) and could cut a line; it is raised when the call has returned."""

        def append_logs(self, logs: list[dict[str, Any]]) -> None:
            with signals_deferred():
                super().append_logs(logs)

        def read_logs(self, log_number_from: int) -> Generator[dict[str, Any], None, None]:
            with signals_deferred():
                logs = list(super().read_logs(log_number_from))
            yield from logs

    _check_journal(path)
    try:
        backend = SignalSafeJournal(str(path))
    except OSError as exc:
        raise ConfigError(f"cannot open the tuning journal ({exc.strerror})", source=path,
                          param="tune_storage", terms={"tune_storage": path},
                          fix="give {tune_storage:name} a writable file") from None  # fmt: skip
    return optuna.storages.JournalStorage(backend)


def _check_journal(path: Path) -> None:
    """Refuse a file that is not an intact tuning journal before anything is appended to it:
    every line one JSON operation of Optuna's journal, the last one ended (a run killed while
    writing leaves it cut, and an append would weld the next operation onto it)."""
    if not path.is_file() or path.stat().st_size == 0:
        return

    def refuse(what: str, fix: str) -> ConfigError:
        return ConfigError(f"the tuning journal {what}", source=path, param="tune_storage",
                           terms={"tune_storage": path}, fix=fix)  # fmt: skip

    other = "name another {tune_storage:name} (or delete the file to start afresh)"
    try:
        text = path.read_bytes().decode("utf-8")
    except (OSError, UnicodeDecodeError):
        raise refuse("is not a journal (binary content)", other) from None
    lines = text.split("\n")
    for number, line in enumerate(lines[:-1], start=1):
        try:
            op = json.loads(line)
        except ValueError:
            op = None
        if not isinstance(op, dict) or "op_code" not in op:
            raise refuse(f"is not a journal of fit --tune (line {number})", other)
    if lines[-1].strip():
        raise refuse(
            f"ends in a cut line {len(lines)} (a run killed while writing?)",
            "cut that last line off to resume the search, or delete the file to start "
            "afresh, or name another {tune_storage:name}",
        )
