"""Evaluation of predictions of any measured signal: per-channel metrics."""

from drafttwin.evaluation.metrics import (
    ChannelMetrics,
    evaluate,
    json_number,
    metrics_frame,
    persistence_forecast,
)

__all__ = ["ChannelMetrics", "evaluate", "json_number", "metrics_frame", "persistence_forecast"]
