"""Neural and hybrid models of the roller speeds (SPEC sections 1-2).

Estimators (scikit-learn style; ``fit(series, mechanistic=None)``, ``predict(series,
mechanistic=None) -> (n, 4) rpm``, ``save(path)``, ``Class.load(path)``):

* :class:`MechanisticBaseline`, :class:`PersistenceModel`,
* :class:`GRUModel`, :class:`LSTMModel` (data-driven),
* :class:`ParallelHybrid`, :class:`MDSL` (``md-s-l``, ``md-l``, ``md-s``, ``+d``).

Build them by name with :func:`make_model`, load any file with :func:`load_model`;
step through a record one sample at a time with :class:`OnlinePredictor`. Every estimator
also takes ``task="simulation"`` (free run), other ``outputs`` and exogenous ``inputs``
(:mod:`drafttwin.models.simulation`, ``docs/emps.md``).
"""

from drafttwin.models.base import FORMAT_VERSION, BaseModel, NotFittedError
from drafttwin.models.datadriven import GRUModel, LSTMModel, MechanisticBaseline, PersistenceModel
from drafttwin.models.hybrid import ParallelHybrid
from drafttwin.models.mdsl import MDSL
from drafttwin.models.mechanistic import MechanisticModel
from drafttwin.models.networks import RecurrentRegressor, ResidualNet, SKConv1d
from drafttwin.models.online import OnlinePredictor
from drafttwin.models.profiles import PROFILES, Profile
from drafttwin.models.registry import MODEL_NAMES, get_profile, load_model, make_model
from drafttwin.models.simulation import TASKS
from drafttwin.models.training import FitProgress, History, TrainConfig, train_network

__all__ = [
    "FORMAT_VERSION",
    "MDSL",
    "MODEL_NAMES",
    "PROFILES",
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
    "TASKS",
    "TrainConfig",
    "get_profile",
    "load_model",
    "make_model",
    "train_network",
]
