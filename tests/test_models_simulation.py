"""task="simulation", other output channels and exogenous inputs (no EMPS data needed).

The system: a damped double integrator driven by an input ``u`` (a carriage under a force),
output ``y`` its position; the "mechanistic" model is the same system with a 5 % gain error,
simulated open loop from ``u`` and the first measured position.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import ConfigError, DataError
from drafttwin.models import MechanisticModel, OnlinePredictor, load_model, make_model
from drafttwin.models.estimators.params import encode_params
from drafttwin.models.training import debias_head

from ._synthetic import TINY, TINY_MDSL

INIT = 8
NAMES = ("mechanistic", "persistence", "gru", "lstm", "parallel", "md-s-l", "md-s-l+d")


def _plant(u: np.ndarray, y0: float, gain: float) -> np.ndarray:
    """Position of a damped double integrator: v' = 0.95 v + gain u, y' = y + v."""
    y, v = np.empty(len(u)), 0.0
    y[0] = y0
    for k in range(len(u) - 1):
        v = 0.95 * v + gain * u[k]
        y[k + 1] = y[k] + v
    return y


def make_io_series(n: int = 500, seed: int = 0) -> MeasurementSeries:
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.normal(0.0, 1.0, n // 25 + 1), 25)[:n]
    y = _plant(u, 0.3, 0.01) + rng.normal(0.0, 1e-4, n)
    return MeasurementSeries(np.arange(n) * 0.01, y[:, None], channels=("y",),
                             inputs={"u": u})  # fmt: skip


def physics() -> MechanisticModel:
    def run(series: MeasurementSeries) -> np.ndarray:
        return _plant(series.inputs["u"], float(series.values[0, 0]), 0.0105)[:, None]

    return MechanisticModel.from_series_function(run, channels=("y",), name="toy physics")


def build(name: str, task: str = "simulation", **extra):
    hyper: dict[str, object] = {"task": task, "outputs": ("y",)}
    if task == "simulation":
        hyper["init_samples"] = INIT
    if name not in ("mechanistic", "persistence"):
        hyper |= {**(TINY_MDSL if name.startswith("md") else TINY), "inputs": ("u",), "seed": 1}
    return make_model(name, **{**hyper, **extra})


@pytest.fixture(scope="module")
def data() -> tuple[MeasurementSeries, MeasurementSeries]:
    full = make_io_series(520, seed=4)
    return full.slice(0, 400), full.slice(400)


@pytest.fixture(scope="module")
def fitted(data) -> dict[str, object]:
    train, _ = data
    return {name: build(name).fit(train, physics()) for name in NAMES}


@pytest.mark.parametrize("name", NAMES)
def test_simulation_never_uses_measured_outputs_after_the_init_window(name, fitted, data):
    _, test = data
    model = fitted[name]
    base = model.predict_values(test, physics())
    assert np.isnan(base[:INIT]).all()  # the measured start is no prediction, for every model
    assert np.isfinite(base[INIT:]).all()
    rng = np.random.default_rng(0)
    changed = test.with_values(test.values + np.r_[np.zeros(INIT), rng.normal(0, 5, len(test) - INIT)]
                            [:, None])  # fmt: skip
    np.testing.assert_array_equal(model.predict_values(changed, physics()), base)
    # the initialisation window is used: changing it changes the free run (the test can fail)
    moved = test.with_values(test.values + np.r_[np.full(INIT, 0.01), np.zeros(len(test) - INIT)]
                          [:, None])  # fmt: skip
    assert not np.array_equal(model.predict_values(moved, physics())[INIT:], base[INIT:])


def test_the_mechanistic_source_sees_nothing_after_the_init_window(fitted, data):
    seen = {}

    def peek(series: MeasurementSeries) -> np.ndarray:
        seen["y"] = series.values[:, 0].copy()
        return physics().predict_values(series)

    fitted["parallel"].predict_values(
        data[1], MechanisticModel.from_series_function(peek, channels=("y",))
    )
    assert np.isfinite(seen["y"][:INIT]).all() and np.isnan(seen["y"][INIT:]).all()


def test_persistence_holds_the_last_init_value(fitted, data):
    pred = fitted["persistence"].predict_values(data[1])
    np.testing.assert_array_equal(pred[INIT:, 0], data[1].values[INIT - 1, 0])


def test_parallel_simulation_accumulates_from_the_measured_residual(data):
    train, test = data
    model = build("parallel", accumulate=True, fallback=False).fit(train, physics())
    mech = physics().predict_values(test)
    assert model.selection_["accumulate"] == {"accumulate": True, "chosen_by": "user",
                                              "validation_nrmse": {}, "validation_rows": 0}  # fmt: skip
    pred = model.predict_values(test, physics())
    first_step = pred[INIT, 0] - mech[INIT, 0] - (test.values[INIT - 1, 0] - mech[INIT - 1, 0])
    assert abs(first_step) < 0.05 * np.ptp(test.values)  # one predicted change, not a level


@pytest.mark.parametrize("name", ["parallel", "md-s-l"])
def test_accumulation_is_chosen_on_validation_data(name):
    """With two training records both variants are trained; the one with the smaller free-run
    error over the held-out records is kept, and the model file records the scores."""
    records = MeasurementSeries.concat([make_io_series(200, seed=4), make_io_series(200, seed=5)])
    model = build(name).fit(records, physics())
    choice = model.selection_["accumulate"]
    scores = choice["validation_nrmse"]
    assert choice["chosen_by"] == "validation folds" and choice["validation_rows"] > 0
    assert model.selection_["correction"]["fold_by"] == "record"
    folds = model.selection_["correction"]["fold_nrmse"]
    for key in ("accumulate", "level"):  # the choice's scores are the folds' means
        assert scores[key] == pytest.approx(np.mean(folds[key]))
    assert set(scores) == {"accumulate", "level"}
    best = min(scores, key=scores.get)
    assert model.accumulate_ is (best == "accumulate") is choice["accumulate"]


@pytest.mark.parametrize("name", ["parallel", "md-s-l"])
def test_one_training_record_predicts_the_level(name, fitted):
    """On one record the folds are blocks of it, shorter than the runs the model will make, so
    accumulated changes (whose error grows with the run) are not offered: the level, judged
    against the physics alone on the blocks, as the selection records."""
    model = fitted[name]
    choice = model.selection_["accumulate"]
    correction = model.selection_["correction"]
    assert choice["chosen_by"] == "one record" and choice["accumulate"] is False
    assert model.accumulate_ is False and correction["fold_by"] == "block"
    assert set(correction["fold_nrmse"]) == {"none", "level"}
    assert choice["validation_nrmse"]["level"] == pytest.approx(
        np.mean(correction["fold_nrmse"]["level"])
    )


def test_hybrid_simulation_beats_the_biased_physics(data):
    train, test = data
    mech = physics()
    model = build("parallel", epochs=40, patience=None, hidden=16).fit(train, mech)
    y = test.values[INIT:, 0]
    err_h = np.sqrt(np.mean((model.predict_values(test, mech)[INIT:, 0] - y) ** 2))
    err_m = np.sqrt(np.mean((mech.predict_values(test)[INIT:, 0] - y) ** 2))
    assert err_h < err_m


@pytest.mark.parametrize("name", ["gru", "parallel", "md-s-l"])
def test_simulation_models_round_trip(name, fitted, data, tmp_path: Path):
    model = fitted[name]
    loaded = load_model(model.save(tmp_path / "m.pt"))
    assert encode_params(loaded.get_params()) == encode_params(model.get_params())
    np.testing.assert_array_equal(loaded.predict_values(data[1], physics()),
                                  model.predict_values(data[1], physics()))  # fmt: skip


def test_same_seed_same_simulation(data):
    a = build("md-s-l").fit(data[0], physics()).predict_values(data[1], physics())
    b = build("md-s-l").fit(data[0], physics()).predict_values(data[1], physics())
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("name", ["gru", "parallel", "md-s-l"])
def test_prediction_mode_with_inputs_is_causal(name, data):
    train, test = data
    keep = {} if name == "gru" else {"fallback": False}  # the residual model, tested or not
    model = build(name, task="prediction", **keep).fit(train, physics())
    base = model.predict_values(test, physics())
    t = 60
    changed = test.with_values(np.r_[test.values[:t, 0], test.values[t:, 0] + 1.0][:, None])
    after = model.predict_values(changed, physics())
    np.testing.assert_array_equal(after[:t], base[:t])
    assert not np.array_equal(after[t:], base[t:])


def test_crossfitted_free_runs_are_out_of_sample(fitted, data):
    model = fitted["md-s-l"]
    a, b = model.crossfit_blocks_[1]
    train = data[0]
    rpm = train.values.copy()
    rpm[a + INIT :] += 1.0  # alter the block after its initialisation rows (and later blocks)
    fold = model._data_model(seed=model.seed + 2)
    u = train.inputs["u"][:, None]
    fold._fit_arrays(train.values, u, (0,), exclude=(a, b))
    run = fold._simulate_arrays(rpm, u, [(a, b)], INIT)
    np.testing.assert_allclose(run[a:b], model.crossfit_pred_[a:b], rtol=0, atol=1e-12)


class _Head(torch.nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.head = torch.nn.Linear(3, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(x)


def test_debias_head_removes_the_mean_error():
    torch.manual_seed(0)
    net = _Head()
    x = np.random.default_rng(0).normal(size=(50, 3)).astype(np.float32)
    target = x @ np.array([[1.0], [0.5], [0.0]]) + 3.0
    debias_head(net, x, target, None, "cpu")
    out = net(torch.as_tensor(x)).detach().numpy()
    assert abs(float(np.mean(target - out))) < 1e-5


@pytest.mark.parametrize(
    ("hyper", "match"),
    [
        ({"task": "forecast"}, "task"),
        ({"window": 12}, "longer than the 8 measured rows"),
        ({"horizon": 2}, "horizon"),
        ({"inputs": ("y",)}, "both inputs and outputs"),
        ({"outputs": ()}, "outputs"),
        ({"init_samples": 0}, "init_samples"),
    ],
)
def test_invalid_task_settings_are_refused(hyper, match, data):
    with pytest.raises(ConfigError, match=match):
        build("gru", **hyper).fit(data[0])


def test_channel_problems_are_refused(data):
    train, _ = data
    with pytest.raises(DataError, match="no input channel 'v'"):
        build("gru", inputs=("v",)).fit(train)
    with pytest.raises(DataError, match="output channels"):
        build("gru", outputs=("x",)).fit(train)
    rollers = MechanisticModel(lambda t: np.zeros((len(t), 4)))
    with pytest.raises(DataError, match=r"expected values of shape \(400, 1\)"):
        build("parallel").fit(train, rollers)
    named = MechanisticModel(lambda t: np.zeros((len(t), 1)), channels=("x",))
    with pytest.raises(DataError, match=r"gives channels \['x'\], not \['y'\]"):
        build("parallel").fit(train, named)
    with pytest.raises(DataError, match="expected a MeasurementSeries"):
        physics().predict(train.time_s)


def test_streaming_refuses_simulation_models(fitted):
    with pytest.raises(ConfigError, match="streaming supports"):
        OnlinePredictor(fitted["gru"])
