"""Evaluation of predictions of any measured signal: per-channel metrics, and the one
split / preprocessing / scoring protocol (:mod:`drafttwin.evaluation.protocol`)."""

from drafttwin.evaluation.metrics import ChannelMetrics, evaluate, json_number, metrics_frame

__all__ = ["ChannelMetrics", "evaluate", "json_number", "metrics_frame"]
