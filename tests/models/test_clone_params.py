"""scikit-learn style composites: nested ``get_params`` / ``set_params`` and ``clone``."""

from __future__ import annotations

import json

import numpy as np
import pytest

import drafttwin as dt
from drafttwin.errors import ConfigError
from drafttwin.models import (
    MDSL,
    MODEL_NAMES,
    GRUModel,
    LSTMModel,
    NotFittedError,
    ParallelHybrid,
    Task,
    Training,
    clone,
    make_model,
)
from drafttwin.models.estimators.base import read_model_file
from drafttwin.models.estimators.params import encode_params

from .._synthetic import hyper_for

CPU = Training(epochs=1, batch_size=64, device="cpu")


def _mdsl() -> MDSL:
    lstm = LSTMModel(window=6, hidden=5, layers=1, training=CPU)
    return MDSL(window=8, hidden=4, layers=1, sk_channels=6, folds=2, data_model=lstm,
                training=CPU, quiet=True, fallback=False)  # fmt: skip


def _values(model: object) -> dict[str, object]:
    """Deep params without the part objects themselves (estimators compare by identity)."""
    return {k: v for k, v in model.get_params().items() if not hasattr(v, "get_params")}


def _fitted(model: object) -> list[str]:
    return [k for k in vars(model) if k.endswith("_") and not k.startswith("_")]


def test_deep_params_add_the_parts_params_with_double_underscores() -> None:
    model = _mdsl()
    shallow = model.get_params(deep=False)
    assert list(shallow) == MDSL.param_names()
    assert shallow["data_model"] is model.data_model
    deep = model.get_params()
    nested = {f"data_model__{k}": v for k, v in model.data_model.get_params().items()}
    assert deep == {**shallow, **nested}
    assert deep["data_model__hidden"] == 5 and deep["data_model__window"] == 6
    # a model without parts: deep and shallow are the same dict
    parallel = ParallelHybrid(hidden=3)
    assert parallel.get_params() == parallel.get_params(deep=False)
    assert not any("__" in k for k in parallel.get_params())


def test_set_params_on_a_part_changes_the_part() -> None:
    model = _mdsl()
    part = model.data_model
    assert model.set_params(data_model__hidden=11, hidden=6) is model
    assert part.hidden == 11 and model.data_model is part and model.hidden == 6
    assert model.get_params()["data_model__hidden"] == 11
    # a part given in the same call takes the nested names
    model.set_params(data_model=GRUModel(layers=1), data_model__window=9)
    assert isinstance(model.data_model, GRUModel) and model.data_model.window == 9
    assert part.window == 6  # the old part is left alone


def test_unknown_nested_names_are_refused_and_nothing_is_set() -> None:
    model = _mdsl()
    for bad in ("data_model__nope", "training__epochs", "nope__hidden", "hidden__x"):
        with pytest.raises(ConfigError, match="unknown hyperparameter") as err:
            model.set_params(hidden=99, data_model__hidden=42, **{bad: 1})
        assert bad in str(err.value) and "data_model__hidden" in str(err.value)
        assert model.hidden == 4 and model.data_model.hidden == 5
    empty = MDSL()  # the default data model (None) has nothing to set on
    with pytest.raises(ConfigError, match="data_model__hidden"):
        empty.set_params(data_model__hidden=3)


def test_clone_is_a_new_unfitted_model_with_equal_params() -> None:
    model = make_model("md-s-l", task="simulation", inputs=["u"], init_samples=30)
    copy = dt.clone(model)
    assert type(copy) is MDSL and copy is not model
    assert _values(copy) == _values(model)
    assert encode_params(copy.get_params(deep=False)) == encode_params(model.get_params(deep=False))
    assert copy.data_model is not model.data_model
    assert copy.training is not model.training and copy.task is not model.task
    copy.set_params(data_model__hidden=1, structure="relative")
    assert model.data_model.hidden != 1 and model.structure == "absolute"
    with pytest.raises(ConfigError, match="not an estimator"):
        clone(dt.MechanisticModel(np.zeros(3)))
    with pytest.raises(ConfigError, match="not an estimator"):
        clone(MDSL)
    for name in MODEL_NAMES:  # every registry model clones to its own kind
        original = make_model(name, task="simulation", init_samples=30)
        again = clone(original)
        assert (type(again), again.name, _values(again)) == (
            type(original), original.name, _values(original)
        )  # fmt: skip


def test_clone_of_a_fitted_hybrid_carries_nothing_fitted(series, mech) -> None:
    model = _mdsl().fit(series, mech)
    assert {"channels_", "data_model_", "net_"} <= set(_fitted(model))
    copy = clone(model)
    assert _fitted(copy) == [] and _fitted(copy.data_model) == []
    assert _values(copy) == _values(model)
    assert copy.data_model is not model.data_model and copy.data_model is not model.data_model_
    with pytest.raises(NotFittedError):
        copy.predict_values(series, mech)
    # the clone is the same recipe: fitted on the same data it predicts the same numbers
    np.testing.assert_allclose(
        copy.fit(series, mech).predict_values(series, mech), model.predict_values(series, mech)
    )
    # and fitting it left the original's parts alone
    assert model.data_model_ is not copy.data_model_ and _fitted(model.data_model) == []


def test_model_files_store_the_shallow_params_as_before(series, mech, tmp_path) -> None:
    model = make_model("md-s-l", **hyper_for("md-s-l")).fit(series, mech)
    path = model.save(tmp_path / "m.dtm")
    stored = json.loads(read_model_file(path)["params_json"])
    assert list(stored) == MDSL.param_names()  # no part__name keys
    assert stored == encode_params(model.get_params(deep=False))
    assert stored["data_model"]["__model__"] == "GRUModel"
    assert list(stored["data_model"]["params"]) == GRUModel.param_names()
    assert stored["task"] == {"__task__": Task().to_dict()}
    again = dt.load_model(path)
    assert again.get_params().keys() == model.get_params().keys()
    assert encode_params(again.get_params(deep=False)) == stored
