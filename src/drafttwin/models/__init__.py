"""Neural and hybrid models of measured outputs (the FA320A roller speeds, or any channels).

Estimators (scikit-learn style; ``fit(series, mechanistic=None)``, ``predict(series,
mechanistic=None)`` -> a labelled frame, ``predict_values`` -> an array, ``save(path)``,
``Class.load(path)``):

* :class:`MechanisticBaseline`, :class:`PersistenceModel`,
* :class:`GRUModel`, :class:`LSTMModel` (data-driven),
* :class:`ParallelHybrid`, :class:`MDSL` (``md-s-l``, ``md-l``, ``md-s``, ``+d``).

Each takes a :class:`Task` (one-step prediction or free-run simulation, output and input
channels) and the networks a :class:`Training`. Build them by name with :func:`make_model`,
load any file with :func:`load_model`, copy one unfitted with :func:`clone`; step through a
record one sample at a time with :class:`OnlinePredictor`.
"""

from drafttwin.models.estimators.base import FORMAT_VERSION, BaseModel, NotFittedError
from drafttwin.models.estimators.baselines import (
    MechanisticBaseline,
    PersistenceModel,
    persistence_forecast,
)
from drafttwin.models.estimators.cloning import clone
from drafttwin.models.estimators.datadriven import GRUModel, LSTMModel
from drafttwin.models.estimators.mdsl import MDSL
from drafttwin.models.estimators.networks import RecurrentRegressor, ResidualNet, SKConv1d
from drafttwin.models.estimators.parallel import ParallelHybrid
from drafttwin.models.estimators.task import TASKS, Task
from drafttwin.models.mechanistic import MechanisticModel
from drafttwin.models.online import OnlinePredictor
from drafttwin.models.profiles import PROFILES, Profile
from drafttwin.models.registry import MODEL_NAMES, get_profile, load_model, make_model
from drafttwin.models.storage.modelfile import DeviceFallbackWarning
from drafttwin.models.training import FitProgress, History, Training, train_network

__all__ = [
    "FORMAT_VERSION",
    "DeviceFallbackWarning",
    "MDSL",
    "MODEL_NAMES",
    "PROFILES",
    "TASKS",
    "BaseModel",
    "FitProgress",
    "GRUModel",
    "History",
    "LSTMModel",
    "MechanisticBaseline",
    "MechanisticModel",
    "NotFittedError",
    "OnlinePredictor",
    "ParallelHybrid",
    "PersistenceModel",
    "Profile",
    "RecurrentRegressor",
    "ResidualNet",
    "SKConv1d",
    "Task",
    "Training",
    "clone",
    "get_profile",
    "load_model",
    "make_model",
    "persistence_forecast",
    "train_network",
]
