"""Online prediction: one row per call from a fitted model (:class:`OnlinePredictor`), and
many machines that share a model in one batch (:func:`forecast_many`), as the live twin runs
them (:mod:`.predictor`)."""

from drafttwin.models.online.predictor import OnlinePredictor, forecast_many

__all__ = ["OnlinePredictor", "forecast_many"]
