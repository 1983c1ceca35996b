"""Never worse than the physics on validation (issue 27, item 1): "no correction" is a
validation candidate of every hybrid, and the residual model is kept only when it beats the
physics there."""

from __future__ import annotations

import numpy as np
import pytest

from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import DataError, ModelFileError
from drafttwin.models import MechanisticModel, load_model, make_model

from ._synthetic import TINY, TINY_MDSL

INIT = 8
N = 400


def _physics_values(u: np.ndarray, time_s: np.ndarray) -> np.ndarray:
    return (np.sin(2 * np.pi * 0.4 * time_s) + 0.5 * u)[:, None]


def _record(bias: float, seed: int = 3) -> MeasurementSeries:
    """y = physics + ``bias`` + white noise: nothing but the bias can be learnt."""
    rng = np.random.default_rng(seed)
    time_s = np.arange(N) * 0.02
    u = np.repeat(rng.normal(0.0, 1.0, N // 40 + 1), 40)[:N]
    y = _physics_values(u, time_s) + bias + rng.normal(0.0, 0.05, (N, 1))
    return MeasurementSeries(time_s, y, channels=("y",), inputs={"u": u})


def physics() -> MechanisticModel:
    def run(series: MeasurementSeries) -> np.ndarray:
        return _physics_values(series.inputs["u"], series.time_s)

    return MechanisticModel.from_series_function(run, channels=("y",), name="exact physics")


def _fit(name: str, train: MeasurementSeries, task: str = "simulation"):
    tiny = TINY_MDSL if name.startswith("md") else TINY
    hyper = {**tiny, "epochs": 4, "task": task, "outputs": ("y",), "inputs": ("u",), "seed": 2}
    if task == "simulation":
        hyper["init_samples"] = INIT
    return make_model(name, **hyper).fit(train, physics())


def _rmse(pred: np.ndarray, y: np.ndarray) -> float:
    ok = np.isfinite(pred[:, 0])
    return float(np.sqrt(np.mean((pred[ok, 0] - y[ok, 0]) ** 2)))


@pytest.mark.parametrize(("name", "task"), [("parallel", "simulation"),
                                            ("parallel", "prediction"),
                                            ("md-s-l", "simulation")])  # fmt: skip
def test_white_noise_residual_leaves_the_physics_alone(name: str, task: str, tmp_path) -> None:
    data = _record(bias=0.0)
    train, test = data.slice(0, 280), data.slice(280)
    model = _fit(name, train, task)
    choice = model.selection_["correction"]
    assert choice["kept"] == "none" and choice["chosen_by"] == "validation folds"
    assert choice["validation_rows"] > 0 and set(choice["validation_nrmse"]) >= {"none"}
    assert choice["folds"] == 3 and all(len(v) == 3 for v in choice["fold_nrmse"].values())
    init = {"init_samples": INIT} if task == "simulation" else {}
    alone = make_model("mechanistic", task=task, outputs=("y",), **init)
    alone.fit(train, physics())
    expected = alone.predict_values(test, physics())
    np.testing.assert_array_equal(model.predict_values(test, physics()), expected)
    model.save(tmp_path / "m.dtm")  # the choice survives the model file
    again = load_model(tmp_path / "m.dtm")
    np.testing.assert_array_equal(again.predict_values(test, physics()), expected)


@pytest.mark.parametrize("name", ["parallel", "md-s-l"])
def test_white_noise_over_several_records_keeps_neither_the_net_nor_the_offset(name) -> None:
    """Whole records as folds offer the measured offset held too: on white noise the mean of
    the initialisation rows is noise as well (its error adds about 1/INIT of the variance),
    so it loses to the physics alone and the hybrid predicts its physics exactly."""
    train = MeasurementSeries.concat([_record(0.0, seed) for seed in (3, 4, 5)])
    test = _record(0.0, seed=6)
    model = _fit(name, train)
    choice = model.selection_["correction"]
    assert choice["fold_by"] == "record" and "offset" in choice["fold_nrmse"], choice
    assert choice["kept"] == "none" and "offset" not in choice, choice
    assert min(choice["fold_nrmse"]["offset"]) > 1.0  # physics alone: 1 on every fold
    alone = make_model("mechanistic", task="simulation", outputs=("y",), init_samples=INIT)
    alone.fit(train, physics())
    np.testing.assert_array_equal(model.predict_values(test, physics()),
                                  alone.predict_values(test, physics()))  # fmt: skip


def test_a_learnable_residual_is_kept_and_beats_the_physics() -> None:
    data = _record(bias=0.4)
    train, test = data.slice(0, 280), data.slice(280)
    model = _fit("parallel", train)
    choice = model.selection_["correction"]
    scores = choice["validation_nrmse"]
    assert choice["kept"] in ("level", "accumulate") and choice["kept"] == (
        "accumulate" if model.accumulate_ else "level"
    )
    assert scores[choice["kept"]] < scores["none"]
    pred, mech = model.predict_values(test, physics()), physics().predict_values(test)
    mech[:INIT] = np.nan
    assert _rmse(pred, test.values) < 0.5 * _rmse(mech, test.values)


def test_fallback_off_keeps_the_residual_model_untested_by_physics() -> None:
    data = _record(bias=0.0)
    model = make_model("parallel", **{**TINY, "task": "simulation", "outputs": ("y",),
                                      "inputs": ("u",), "init_samples": INIT,
                                      "fallback": False}).fit(data.slice(0, 280), physics())  # fmt: skip
    choice = model.selection_["correction"]
    assert choice["chosen_by"] == "user" and choice["kept"] != "none"
    pred = model.predict_values(data.slice(280), physics())
    assert not np.allclose(pred[INIT:], physics().predict_values(data.slice(280))[INIT:])


def test_mdsl_shares_a_data_model_through_its_public_api() -> None:
    """fit_data_model + use_data_model give the same hybrid as one fit (same seed); another
    training part is refused."""
    data = _record(bias=0.4)
    train, test = data.slice(0, 160), data.slice(160, 220)
    hyper = {**TINY_MDSL, "task": "simulation", "outputs": ("y",), "inputs": ("u",),
             "init_samples": INIT, "seed": 4}  # fmt: skip
    whole = make_model("md-s-l", **hyper).fit(train, physics())
    donor = make_model("md-s-l", **hyper)
    oof = donor.fit_data_model(train)
    assert oof.shape == train.values.shape and donor.data_model_.channels_ == ("y",)
    shared = make_model("md-s-l", **hyper)
    shared.use_data_model(donor.data_model_, oof, donor.crossfit_blocks_).fit(train, physics())
    np.testing.assert_array_equal(shared.predict_values(test, physics()),
                                  whole.predict_values(test, physics()))  # fmt: skip
    other = make_model("md-s-l", **hyper).use_data_model(donor.data_model_, oof[:-5],
                                                          donor.crossfit_blocks_)  # fmt: skip
    with pytest.raises(DataError, match="same training rows"):
        other.fit(train, physics())


def _two_physics(time_s: np.ndarray) -> np.ndarray:
    return np.column_stack([np.sin(2 * np.pi * 0.4 * time_s), np.cos(2 * np.pi * 0.3 * time_s)])


def _two_channels(seed: int = 3) -> MeasurementSeries:
    """Channel ``a``: physics + a slowly wandering offset (AR(1), learnable one step ahead);
    ``b``: physics + white noise (nothing to learn)."""
    rng = np.random.default_rng(seed)
    time_s = np.arange(N) * 0.02
    wander = np.zeros(N)
    for i in range(1, N):
        wander[i] = 0.97 * wander[i - 1] + rng.normal(0.0, 0.08)
    noise = rng.normal(0.0, 0.05, (N, 2))
    y = _two_physics(time_s) + np.column_stack([0.4 + wander, np.zeros(N)]) + noise
    return MeasurementSeries(time_s, y, channels=("a", "b"))


def test_a_correction_is_kept_per_output_channel(tmp_path) -> None:
    """One channel's residual is learnable, the other's white noise: the residual model
    corrects the first and leaves the second to its physics, exactly, in batch, after the
    model file and on the stream (live = offline)."""
    from drafttwin.models import OnlinePredictor

    data, mech = _two_channels(), MechanisticModel(_two_physics)
    train, test = data.slice(0, 280), data.slice(280)
    hyper = {**TINY, "epochs": 6, "task": "prediction", "outputs": ("a", "b"), "seed": 2}
    model = make_model("parallel", **hyper).fit(train, mech)
    choice = model.selection_["correction"]
    assert choice["kept"] == "residual" and choice["corrected"] == {"a": True, "b": False}, choice
    assert choice["channel_wins"]["a"] == 3, choice
    pred, physics_alone = model.predict_values(test, mech), mech.predict_values(test)
    np.testing.assert_array_equal(pred[:, 1], physics_alone[:, 1])
    ok = np.isfinite(pred[:, 0])
    assert _rmse(pred[:, :1], test.values[:, :1]) < 0.5 * _rmse(physics_alone[ok, :1],
                                                                 test.values[ok, :1])  # fmt: skip
    model.save(tmp_path / "m.dtm")
    again = load_model(tmp_path / "m.dtm")
    np.testing.assert_array_equal(again.predict_values(test, mech), pred)
    online = OnlinePredictor(again, mech)
    steps = []
    for i in range(len(test)):
        steps.append(online.forecast(float(test.time_s[i])))
        online.observe(float(test.time_s[i]), test.values[i])
    np.testing.assert_allclose(np.array(steps), pred, rtol=0, atol=1e-3, equal_nan=True)
    for bad in ([True], [True, "no"], "all"):  # read back checked: one bool per channel
        damaged = tmp_path / f"bad{len(bad)}.dtm"
        _rewrite_state(tmp_path / "m.dtm", damaged, corrected=bad)
        with pytest.raises(ModelFileError, match="corrected"):
            load_model(damaged)


def _rewrite_state(good, target, **fields) -> None:
    """A copy of the model file with state fields replaced (checksum resealed, as a forger
    would)."""
    import json

    import torch

    from drafttwin.models.storage.modelfile import checksum

    payload = torch.load(good, weights_only=True)
    state = json.loads(payload["state_json"])
    state.update(fields)
    payload["state_json"] = json.dumps(state)
    payload["checksum"] = checksum(payload)
    torch.save(payload, target)
