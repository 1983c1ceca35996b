"""drafttwin: mechanism-data hybrid models of drive trains, with the FA320A drawing frame's
drafting section built in.

The public API in one place (``import drafttwin as dt``)::

    series = dt.read_measurements("run.csv", outputs=["y"], inputs=["u"], units={"y": "m"})
    physics = dt.MechanisticModel.from_config("my_train.toml")    # or a simulator output file
    model = dt.make_model("md-s-l", task="simulation", inputs=["u"], init_samples=20)
    test = dt.read_measurements("test.csv", outputs=["y"], inputs=["u"], units={"y": "m"})
    part = dt.fit_split(model, series, test=test, mechanistic=physics)  # dt.fit: the model
    frame = model.predict(part.test, physics)        # time + one column per output channel
    print(dt.evaluate(model, part, mechanistic=physics).to_frame())

    # the sliver: fibres drafted through the rollers' surface speeds, evenness, chimneys
    speeds = dt.SurfaceSpeeds.from_rpm(series.time_s, rpm, {"front": 45.0, ...})
    sliver = dt.draft_sliver(speeds, dt.Feed(dt.StapleDiagram.preset("cotton"), 6, 5.5))
    dx = dt.diagnose_sliver(sliver, dt.DriveTrain.preset("fa320a"), sliver.staple)

Names are loaded on first use, so ``import drafttwin`` stays light (PyTorch and numba load
with the models and the mechanics).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from drafttwin._constants import ROLLERS, __version__
from drafttwin._numba_cache import ensure_numba_cache

ensure_numba_cache()

_EXPORTS: dict[str, str] = {
    # measurements
    "MeasurementSeries": "drafttwin.data.series",
    "read_measurements": "drafttwin.data.io",
    "write_measurements": "drafttwin.data.io",
    "preprocess": "drafttwin.data.preprocessing",
    "load_default": "drafttwin.datasets",
    # physics
    "DriveTrain": "drafttwin.mechanics",
    "kinematics": "drafttwin.mechanics",
    "simulate": "drafttwin.mechanics",
    # models
    "MechanisticModel": "drafttwin.models",
    "Task": "drafttwin.models",
    "Training": "drafttwin.models",
    "make_model": "drafttwin.models",
    "load_model": "drafttwin.models",
    "clone": "drafttwin.models",
    "MODEL_NAMES": "drafttwin.models",
    "GRUModel": "drafttwin.models",
    "LSTMModel": "drafttwin.models",
    "ParallelHybrid": "drafttwin.models",
    "MDSL": "drafttwin.models",
    "MechanisticBaseline": "drafttwin.models",
    "PersistenceModel": "drafttwin.models",
    # the evaluation protocol
    "split": "drafttwin.evaluation.protocol",
    "fit": "drafttwin.application",
    "FitRequest": "drafttwin.application",
    "run_fit": "drafttwin.application",
    "fit_split": "drafttwin.evaluation.protocol",
    "evaluate": "drafttwin.evaluation.protocol",
    "Evaluation": "drafttwin.evaluation.protocol",
    # the sliver
    "StapleDiagram": "drafttwin.sliver",
    "Feed": "drafttwin.sliver",
    "FeedFault": "drafttwin.sliver",
    "SurfaceSpeeds": "drafttwin.sliver",
    "Sliver": "drafttwin.sliver",
    "read_sliver": "drafttwin.sliver",
    "draft_sliver": "drafttwin.sliver",
    "evenness": "drafttwin.sliver",
    "spectrogram": "drafttwin.sliver",
    "wavelength_table": "drafttwin.sliver",
    "diagnose_sliver": "drafttwin.sliver",
    # errors
    "DrafttwinError": "drafttwin.errors",
    "ConfigError": "drafttwin.errors",
    "DataError": "drafttwin.errors",
    "ModelFileError": "drafttwin.errors",
}

__all__ = [
    "ROLLERS",
    "__version__",
    "MeasurementSeries",
    "read_measurements",
    "write_measurements",
    "preprocess",
    "load_default",
    "DriveTrain",
    "kinematics",
    "simulate",
    "MechanisticModel",
    "Task",
    "Training",
    "make_model",
    "load_model",
    "clone",
    "MODEL_NAMES",
    "GRUModel",
    "LSTMModel",
    "ParallelHybrid",
    "MDSL",
    "MechanisticBaseline",
    "PersistenceModel",
    "split",
    "fit",
    "FitRequest",
    "run_fit",
    "fit_split",
    "evaluate",
    "Evaluation",
    "StapleDiagram",
    "Feed",
    "FeedFault",
    "SurfaceSpeeds",
    "Sliver",
    "read_sliver",
    "draft_sliver",
    "evenness",
    "spectrogram",
    "wavelength_table",
    "diagnose_sliver",
    "DrafttwinError",
    "ConfigError",
    "DataError",
    "ModelFileError",
]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'drafttwin' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(__all__)


if TYPE_CHECKING:  # for type checkers and IDEs; at run time the names load lazily
    from drafttwin.application import FitRequest, fit, run_fit
    from drafttwin.data.io import read_measurements, write_measurements
    from drafttwin.data.preprocessing import preprocess
    from drafttwin.data.series import MeasurementSeries
    from drafttwin.datasets import load_default
    from drafttwin.errors import ConfigError, DataError, DrafttwinError, ModelFileError
    from drafttwin.evaluation.protocol import Evaluation, evaluate, fit_split, split
    from drafttwin.mechanics import DriveTrain, kinematics, simulate
    from drafttwin.models import (
        MDSL,
        MODEL_NAMES,
        GRUModel,
        LSTMModel,
        MechanisticBaseline,
        MechanisticModel,
        ParallelHybrid,
        PersistenceModel,
        Task,
        Training,
        clone,
        load_model,
        make_model,
    )
    from drafttwin.sliver import (
        Feed,
        FeedFault,
        Sliver,
        StapleDiagram,
        SurfaceSpeeds,
        diagnose_sliver,
        draft_sliver,
        evenness,
        read_sliver,
        spectrogram,
        wavelength_table,
    )
