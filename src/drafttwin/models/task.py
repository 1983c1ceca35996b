"""The task, where other packages (the fault study) import it from; it lives in
:mod:`drafttwin.models.estimators.task`."""

from drafttwin.models.estimators.task import Task

__all__ = ["Task"]
