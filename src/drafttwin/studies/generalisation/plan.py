"""What the generalisation benchmark runs: the configuration (:class:`GeneralisationConfig`,
:data:`QUICK` for the test suite and the study report, :data:`FULL`), each model's options
(:func:`hyperparameters`), and the fits it expands to: one per (task, model, training length,
seed) (:func:`fit_configs`) and the hybrids' structure candidates on the validation records
(:func:`selection_configs`)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from drafttwin._constants import ROLLERS
from drafttwin.errors import ConfigError
from drafttwin.models.estimators.hybrid import FADES, STRUCTURES
from drafttwin.studies.generalisation import records as R
from drafttwin.studies.generalisation.fits import INPUT

MODELS = ("mechanistic", "persistence", "gru", "parallel", "md-s-l")
"""The CLI's model names; ``mechanistic`` is the physics alone."""
LEARNED = ("gru", "parallel", "md-s-l")
HYBRIDS = ("parallel", "md-s-l")
TASKS = ("prediction", "simulation")
CALIBRATED_SCENARIOS = ("other-machine",)
"""Where the physics calibrated on the training record is scored beside the nominal one."""


@dataclass(frozen=True)
class GeneralisationConfig:
    """What :func:`run_benchmark` runs.

    Attributes:
        name: ``full`` or ``quick`` (a subset sized for the test suite).
        seeds: seeds (0 .. seeds-1) per learned model and training length.
        train_lengths_s: learning-curve training lengths (prefixes of the training record);
            the longest also trains the models scored on every other scenario.
        test_s / validation_s: length of each test record / of the validation record.
        rate_hz: sample rate of every record.
        window, hidden, layers, folds, epochs, patience, stride: network settings (the
            data-driven and the residual models alike; MD-S-L's GRU has the GRU's size).
        calibrate_s: seconds of the training record the physics is calibrated on.
        calibrate_params: the parameters calibrated (``None``: calibration's default set).
        workers: parallel processes for the fits.
    """

    name: str = "full"
    seeds: int = 3
    train_lengths_s: tuple[float, ...] = (10.0, 30.0, 90.0, 300.0)
    test_s: float = 20.0
    validation_s: float = 20.0
    rate_hz: float = 100.0
    window: int = 20
    hidden: int = 32
    layers: int = 1
    folds: int = 3
    epochs: int = 15
    patience: int | None = 3
    stride: int = 4
    calibrate_s: float = 60.0
    calibrate_params: tuple[str, ...] | None = None
    workers: int = 1
    models: tuple[str, ...] = MODELS
    tasks: tuple[str, ...] = TASKS
    scenarios: tuple[str, ...] = field(default=R.SCENARIOS)

    @property
    def train_s(self) -> float:
        return max(self.train_lengths_s)

    @property
    def skip_rows(self) -> int:
        """Rows at the start of each test record left unscored for every model: the free
        run's measured start plus one window (so every model is scored on the same rows)."""
        return 2 * self.window

    def check(self) -> None:
        """Refuse settings that cannot run (ConfigError naming the option)."""
        if self.seeds < 1 or self.workers < 1:
            raise ConfigError("seeds and workers must be >= 1", where="--seeds/--workers")
        min_s = 4 * (self.folds + 1) * (2 * self.window + 1) / self.rate_hz
        if min(self.train_lengths_s) < min_s:
            raise ConfigError(f"training lengths must be at least {min_s:g} s",
                              where="train_lengths_s", fix="use longer training records")  # fmt: skip


QUICK = GeneralisationConfig(
    name="quick", seeds=1, train_lengths_s=(3.0, 6.0), test_s=3.0, validation_s=3.0,
    window=10, hidden=8, layers=1, folds=2, epochs=2, patience=None, stride=2, calibrate_s=3.0,
    calibrate_params=("motor.rated_slip", "drafting_zone.main.force_n",
                      "roller.front.friction_coefficient"),
)  # fmt: skip
FULL = GeneralisationConfig()


def get_config(quick: bool, **changes: Any) -> GeneralisationConfig:
    """The quick or full configuration with ``changes`` applied."""
    return replace(QUICK if quick else FULL, **changes)


def hyperparameters(name: str, task: str, config: GeneralisationConfig, seed: int,
                    extra: dict[str, Any] | None = None) -> dict[str, Any]:  # fmt: skip
    """Options of model ``name`` for :func:`~drafttwin.models.make_model` (profile quick,
    overridden by the benchmark's network settings)."""
    wanted: dict[str, Any] = {"task": task, "outputs": ROLLERS}
    if task == "simulation":
        wanted["init_samples"] = config.window
    if name not in LEARNED:
        return wanted
    wanted |= {"inputs": (INPUT,), "window": config.window, "hidden": config.hidden,
               "layers": config.layers, "seed": seed, "quiet": True, "device": "cpu",
               "epochs": config.epochs, "patience": config.patience, "stride": config.stride}  # fmt: skip
    if name == "md-s-l":
        wanted |= {"data_window": config.window, "data_hidden": config.hidden,
                   "data_layers": config.layers, "folds": config.folds}  # fmt: skip
    return wanted | (extra or {})


TORCH_THREADS = 1
"""Threads per fit: these networks are small, so a second intra-op thread only spins (measured
on 2 cores: a 1 x 8 GRU step costs 0.14 ms of CPU on one thread, 4 ms on two); parallelism
comes from ``workers``."""


def fit_configs(config: GeneralisationConfig, path: Path,
                structures: dict[tuple[str, str], dict[str, Any]] | None = None) -> list[dict[str, Any]]:  # fmt: skip
    """One task per (task, model, training length, seed); the longest training length is
    scored on every scenario, the shorter ones on the little-data test record only."""
    structures = structures or {}
    threads = TORCH_THREADS
    others = [s for s in config.scenarios if s != "little-data"]
    out = []
    for task in config.tasks:
        for name in config.models:
            learned = name in LEARNED
            lengths = config.train_lengths_s if learned else (config.train_s,)
            for train_s in lengths:
                for seed in range(config.seeds) if learned else [0]:
                    tests: list[list[str]] = []
                    if "little-data" in config.scenarios:
                        tests.append(["little-data", "nominal", "little-data"])
                    if train_s == config.train_s:
                        tests += [[s, "nominal", s] for s in others]
                    extra = structures.get((name, task))
                    base = {"task": task, "model": name, "train_s": train_s, "seed": seed,
                            "skip_rows": config.skip_rows, "_records": str(path),
                            "_threads": threads, "tests": tests, "physics": "nominal",
                            "hyper": hyperparameters(name, task, config, seed, extra)}  # fmt: skip
                    out.append(base)
                    if name == "mechanistic":
                        cal = [[s, "calibrated", s] for s in CALIBRATED_SCENARIOS
                               if s in config.scenarios]  # fmt: skip
                        if cal:
                            out.append({**base, "tests": cal, "physics": "calibrated"})
    return out


def selection_configs(config: GeneralisationConfig, path: Path) -> list[dict[str, Any]]:
    """Item 2's choice: each hybrid in each task fitted (seed 0, full length) with each
    structure (and, one step ahead, with and without the skip onto the last residual), scored
    on the validation records without fade, with it and with the strict fade; the physics on
    the same records is the yardstick."""
    tests = [[k, "nominal", k] for k in R.VALIDATION_RECORDS]
    base = {"train_s": config.train_s, "seed": 0, "skip_rows": config.skip_rows,
            "_records": str(path), "_threads": TORCH_THREADS, "tests": tests,
            "physics": "nominal"}  # fmt: skip
    out = [
        {
            **base,
            "task": task,
            "model": "mechanistic",
            "hyper": hyperparameters("mechanistic", task, config, 0),
        }
        for task in config.tasks
    ]
    out += [{**base, "task": task, "model": name, "fade_variants": list(FADES),
             "hyper": hyperparameters(name, task, config, 0, {"structure": structure, "skip": skip})}
            for task in config.tasks for name in HYBRIDS if name in config.models
            for skip in skip_options(task) for structure in STRUCTURES]  # fmt: skip
    return out


def skip_options(task: str) -> tuple[bool | None, ...]:
    """The skip options of a task: one step ahead the default (onto the last residual) and
    none; a free run has no measured residual to skip onto."""
    return (None, False) if task == "prediction" else (None,)
