"""The application layer: one path for the library and the command line.

A fit is a typed request (:class:`FitRequest`) that owns the physics source, the defaults,
the model's construction, the split, the tuning and the provenance; :func:`run_fit` carries it
out and :func:`fit` is ``dt.fit``. The command line parses its options into a request and
prints the result; it decides nothing itself."""

from drafttwin.application.fitting import FitResult, fit, plan_physics, run_fit
from drafttwin.application.physics import resolve_physics
from drafttwin.application.request import FitNote, FitRequest, Note, build_model, setting_names

__all__ = [
    "FitNote",
    "FitRequest",
    "FitResult",
    "Note",
    "build_model",
    "fit",
    "plan_physics",
    "resolve_physics",
    "run_fit",
    "setting_names",
]
