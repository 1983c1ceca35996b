"""Study plans: how much of the paper's study each plan runs, stated for the report.

A plan is chosen by ``drafttwin reproduce --plan NAME`` (``--profile`` is its second name);
it names the models' hyperparameter profile it trains with (``model_profile``,
:mod:`drafttwin.models.profiles`), which is another thing. The results file keeps the plan
under its old key ``"profile"``, and the plans' notes keep their wording, so the report and
saved results read as before.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import Any

from drafttwin.errors import unknown_choice

GRID_LR = (0.001, 0.005, 0.01)
GRID_HIDDEN = (64, 128, 256)
GRID_LAYERS = (2, 3)
GRID_NETS = ("lstm", "gru")


@dataclass(frozen=True)
class StudyPlan:
    """Budget of one ``drafttwin reproduce`` run.

    Attributes:
        model_profile: the models' hyperparameter profile (``drafttwin.models.profiles``).
        data_duration_s: seconds of the data set used (``None`` = all of it).
        epochs, patience: override the model profile's training length (``None`` = keep).
        schedule: override the model profile's learning-rate schedule (``None`` = keep); the
            quick plan keeps the constant rate its tables were made with (6 epochs along a
            cosine gave the GRU a 5 % higher front-roller RMSE).
        residual_layers: override the model profile's residual LSTM layers (``None`` = keep);
            the quick plan keeps the two its tables were made with (the quick profile's one
            since 2026-12-01 is chosen for ``fit``'s time, docs/models.md "Training").
        grid_epochs, grid_patience, grid_train_samples: budget of each grid-search fit
            (the last ``grid_train_samples`` of the training part; ``None`` = all).
        use_grid_best: fit the comparison with the grid winners (the paper's procedure);
            ``False`` keeps the model profile's sizes (the quick plan, to fit its budget).
        ablation_tests: repeated tests (seeds) of the ablation.
        shared_data_model: the ablation's tests share one cross-fitted GRU and vary the
            residual model's seed only (quick); otherwise each test refits the GRU too.
    """

    name: str
    model_profile: str
    data_duration_s: float | None
    epochs: int | None
    patience: int | None
    grid_epochs: int
    grid_patience: int | None
    grid_train_samples: int | None
    use_grid_best: bool
    ablation_tests: int = 10
    shared_data_model: bool = False
    schedule: str | None = None
    residual_layers: int | None = None
    notes: tuple[str, ...] = field(default=())

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


_STANDARD = StudyPlan(
    name="standard",
    model_profile="standard",
    data_duration_s=None,
    epochs=None,
    patience=None,
    grid_epochs=30,
    grid_patience=5,
    grid_train_samples=None,
    use_grid_best=True,
    notes=("standard profile: the whole data set, grid winners used, full repeats",),
)

STUDY_PLANS: dict[str, StudyPlan] = {
    "quick": StudyPlan(
        name="quick",
        model_profile="quick",
        data_duration_s=90.0,
        epochs=6,
        patience=2,
        grid_epochs=1,
        grid_patience=None,
        grid_train_samples=1500,
        use_grid_best=False,
        shared_data_model=True,
        schedule="constant",
        residual_layers=2,
        notes=(
            "quick profile: the first 90 s of the data set; networks of the quick model profile "
            "(2 x 48: its residual LSTM kept at two layers) trained for at most 6 epochs at a "
            "constant rate with early stopping (patience 2)",
            "grid search at a reduced budget (1 epoch on the last 1500 training samples per "
            "configuration): its losses rank configurations only roughly, and the comparison "
            "does not use its winners (standard and paper do)",
            "ablation: the 10 repeated tests share one cross-fitted GRU and vary the residual "
            "model's seed",
        ),
    ),
    "standard": _STANDARD,
    # the standard plan at the paper's budget: its model profile and a full-length grid search
    "paper": replace(
        _STANDARD,
        name="paper",
        model_profile="paper",
        grid_epochs=500,
        grid_patience=None,
        notes=("paper profile: the paper's settings (500 epochs, batch 10); GPU recommended",),
    ),
}


def get_study_plan(name: str) -> StudyPlan:
    try:
        return STUDY_PLANS[name]
    except KeyError:
        raise unknown_choice(f"unknown plan '{name}'", STUDY_PLANS, where="--plan") from None


def grid_configs(plan: StudyPlan, window: int, seed: int = 0) -> list[dict[str, Any]]:
    """The paper's 2 x 18 grid (Fig. 7) as task configurations."""
    return [
        {
            "net": net,
            "lr": lr,
            "hidden": h,
            "layers": nl,
            "window": window,
            "seed": seed,
            "epochs": plan.grid_epochs,
            "patience": plan.grid_patience,
            "train_samples": plan.grid_train_samples,
        }  # fmt: skip
        for net in GRID_NETS
        for lr in GRID_LR
        for h in GRID_HIDDEN
        for nl in GRID_LAYERS
    ]
