"""The estimators' base, where other packages (the live twin) import it from; it lives in
:mod:`drafttwin.models.estimators.base`."""

from drafttwin.models.estimators.base import BaseModel, NotFittedError, is_estimator

__all__ = ["BaseModel", "NotFittedError", "is_estimator"]
