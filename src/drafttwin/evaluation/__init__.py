"""Evaluation of roller-speed predictions: per-roller metrics (SPEC section 3)."""

from drafttwin.evaluation.metrics import (
    RollerMetrics,
    evaluate,
    metrics_frame,
    persistence_forecast,
)

__all__ = ["RollerMetrics", "evaluate", "metrics_frame", "persistence_forecast"]
