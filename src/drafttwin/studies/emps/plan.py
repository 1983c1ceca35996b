"""What the EMPS benchmark runs: the models, tasks and seeds (:class:`EmpsConfig`), each
model's options on the official protocol (:func:`hyperparameters`), one task configuration per
(task, model, seed) (:func:`task_configs`), and the literature numbers beside ours
(:data:`PUBLISHED`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypedDict

from drafttwin.datasets.emps import INIT_SAMPLES, INPUT, OUTPUT
from drafttwin.errors import ConfigError
from drafttwin.studies.emps.physics import EmpsPhysics

MODELS = ("mechanistic", "persistence", "gru", "lstm", "parallel", "md-s-l")
"""Models of the benchmark; ``mechanistic`` is the physics-only model."""
TASKS = ("simulation", "prediction")
DETERMINISTIC = ("mechanistic", "persistence")
"""Models without training: run once per task, not once per seed."""
PHYSICS = ("published", "refitted")
"""Physics variants: the published IDIM-LS parameters, or M, Fv, Fc, offset refitted on the
training record by output error (:func:`~drafttwin.studies.emps.physics.refit`)."""
PHYSICS_MODELS = ("mechanistic", "parallel", "md-s-l")
"""Models that use the physics: run once per physics variant; the others once."""

WINDOW = INIT_SAMPLES
"""Input window of every network: the 20-sample initialisation window of the protocol."""
PREDICTION_START = INIT_SAMPLES + WINDOW
"""First scored row in prediction mode: MD-S-L's residual windows need ``WINDOW`` rows of
the GRU's predictions, which themselves start at row ``WINDOW``."""

PROFILE_ADAPTATION: dict[str, dict[str, Any]] = {
    "quick": {"stride": 5},
    "standard": {"stride": 2},
    "paper": {},
}
"""EMPS changes to the drafttwin profiles (beside the 20-sample windows): the records hold
25,000 samples at 1 kHz, so the quick and standard profiles train on every 5th / 2nd
window (neighbouring windows differ by one sample of 20)."""


class Published(TypedDict):
    """A literature result: the RMSE (mm) and where it comes from."""

    rmse_mm: float
    source: str


PUBLISHED: dict[str, Published] = {
    "mechanistic": {
        "rmse_mm": 9.23,
        "source": "computed in the data set's README (RK4, 10 steps per ms, ZOH vir, q(0) = "
        "qm(0), q'(0) = 0, symmetric IDIM-LS parameters of Janot et al. 2019); not a "
        "published number",
    },
    "lstm": {
        "rmse_mm": 74.1,
        "source": "Champneys et al. 2024, IFAC-PapersOnLine 58(15), companion repository "
        "MDCHAMP/nonlinear_baselines: trained on the first half of DATA_EMPS, validated on the "
        "second half; test-output std 82.7 mm, so these models barely beat the mean",
    },
    "gru": {"rmse_mm": 220.3, "source": "Champneys et al. 2024 (as LSTM)"},
}
"""Literature numbers for the simulation task, from the data set's README (with caveats)."""


@dataclass(frozen=True)
class EmpsConfig:
    """What :func:`run_benchmark` runs.

    Attributes:
        data_dir: folder of the EMPS files (``None``: search, see :mod:`.emps_data`).
        seeds: number of seeds (0 .. seeds-1) for the trained models.
        profile: drafttwin training profile (quick, standard, paper).
        models / tasks: subsets of :data:`MODELS` / :data:`TASKS`.
        epochs: override of the profile's epoch budget (``None``: the profile's).
        max_samples: use only the first samples of each record (smoke tests; the official
            protocol uses all).
        train_metrics: also score the free run / predictions on the training record.
        workers: parallel processes (1: in this process).
        device: torch device for the networks.
        physics: the published physics (what ``refitted`` starts from).
        physics_variants: subset of :data:`PHYSICS` the physics-based models run on.
    """

    data_dir: Path | None = None
    seeds: int = 3
    profile: str = "quick"
    models: tuple[str, ...] = MODELS
    tasks: tuple[str, ...] = TASKS
    epochs: int | None = None
    max_samples: int | None = None
    train_metrics: bool = False
    workers: int = 1
    device: str = "auto"
    physics: EmpsPhysics = field(default_factory=EmpsPhysics)
    physics_variants: tuple[str, ...] = ("published",)

    def check(self) -> None:
        """Refuse unknown models, tasks, profiles and out-of-range numbers (ConfigError)."""
        from drafttwin.models import get_profile

        get_profile(self.profile)
        for what, values, allowed in (("--models", self.models, MODELS),
                                      ("--tasks", self.tasks, TASKS),
                                      ("--physics", self.physics_variants, PHYSICS)):  # fmt: skip
            bad = [v for v in values if v not in allowed]
            if bad or not values:
                both = " (or both)" if what == "--physics" else ""
                raise ConfigError(f"unknown or no entries {bad}", where=what,
                                  fix=f"use a comma-separated subset of {', '.join(allowed)}{both}")  # fmt: skip
        from drafttwin.models.training.compute import _valid_device, device_available

        if not _valid_device(self.device) or not device_available(self.device):
            raise ConfigError(f"device {self.device!r} is not one this machine trains on",
                              where="--device", fix="use --device auto (a GPU where there is "
                              "one) or cpu")  # fmt: skip
        if self.seeds < 1 or self.workers < 1 or (self.epochs is not None and self.epochs < 1):
            raise ConfigError("seeds, workers and epochs must be >= 1", where="options")
        if self.max_samples is not None and self.max_samples < 4 * (INIT_SAMPLES + WINDOW):
            raise ConfigError(f"--max-samples {self.max_samples} is too short",
                              where="--max-samples",
                              fix=f"use at least {4 * (INIT_SAMPLES + WINDOW)} samples")  # fmt: skip


def hyperparameters(name: str, task: str, config: EmpsConfig, seed: int) -> dict[str, Any]:
    """Options of model ``name`` for :func:`~drafttwin.models.make_model` in the benchmark
    (profile + EMPS settings); the models without learning take the task only."""
    wanted: dict[str, Any] = {"task": task, "outputs": (OUTPUT,)}
    if task == "simulation":
        wanted["init_samples"] = INIT_SAMPLES
    if name in DETERMINISTIC:
        return wanted
    wanted |= {"inputs": (INPUT,), "window": WINDOW, "seed": seed, "quiet": True,
               "device": config.device, **PROFILE_ADAPTATION[config.profile]}  # fmt: skip
    if name in ("md-s-l", "md-l", "md-s", "md-s-l+d"):
        wanted["data_window"] = WINDOW
    if config.epochs is not None:
        wanted["epochs"] = config.epochs
    return wanted


def task_configs(config: EmpsConfig, refitted: EmpsPhysics | None = None) -> list[dict[str, Any]]:
    """One configuration per (task, model, physics variant, seed); deterministic models get
    seed 0 only, models outside :data:`PHYSICS_MODELS` one variant (they ignore the physics).
    ``refitted`` is the refitted physics (``None``: the published one stands in, for counting
    tasks before the refit). A published-physics configuration is what it was before the
    variants existed (the variant's name is a ``_`` context entry), so its task key is too."""
    variants = {"published": config.physics, "refitted": refitted or config.physics}
    out = []
    for task in config.tasks:
        for name in config.models:
            seeds = [0] if name in DETERMINISTIC else range(config.seeds)
            kinds = config.physics_variants if name in PHYSICS_MODELS else (None,)
            for kind, seed in ((k, s) for k in kinds for s in seeds):
                physics = variants["published" if kind is None else kind]
                out.append({
                    "task": task, "model": name, "seed": seed, "profile": config.profile,
                    "hyper": hyperparameters(name, task, config, seed),
                    "max_samples": config.max_samples, "train_metrics": config.train_metrics,
                    "physics": physics.to_dict(), "trace": seed == 0, "_physics_name": kind,
                    "_data_dir": None if config.data_dir is None else str(config.data_dir),
                    "_threads": max(1, _cpus() // config.workers),
                })  # fmt: skip
    return out


def variant_name(model: str, physics: str | None) -> str:
    """A model's name with its physics variant: ``parallel``, ``parallel_refitted``."""
    return model if physics in (None, "published") else f"{model}_{physics}"


def _cpus() -> int:
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def score_start(task: str) -> int:
    """First scored test row: 20 (simulation, official) or 40 (prediction, see above)."""
    return INIT_SAMPLES if task == "simulation" else PREDICTION_START
