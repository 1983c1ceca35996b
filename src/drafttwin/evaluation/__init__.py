"""Evaluation of predictions of any measured signal: per-channel metrics, the accuracy limits
on data with known true values (:mod:`drafttwin.evaluation.limits`), and the one split /
preprocessing / scoring protocol (:mod:`drafttwin.evaluation.protocol`)."""

from drafttwin._io import json_number
from drafttwin.evaluation.limits import ChannelLimits, accuracy_limits, floor_oracle, floor_rows
from drafttwin.evaluation.metrics import (
    ChannelMetrics,
    channel_metrics,
    metrics_frame,
)

__all__ = [
    "ChannelLimits",
    "ChannelMetrics",
    "accuracy_limits",
    "channel_metrics",
    "floor_oracle",
    "floor_rows",
    "json_number",
    "metrics_frame",
]
