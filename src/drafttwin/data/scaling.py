"""Min-max normalisation fitted on training data only (paper eq. 14)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray


class MinMaxScaler:
    """Per-column min-max scaling to [0, 1]: ``x' = (x - min) / (max - min)``.

    Fit it on the training part only; ``NaN`` values are ignored when fitting. A constant
    column (max == min) is mapped to 0 rather than dividing by zero.
    """

    def fit(self, x: np.ndarray) -> MinMaxScaler:
        x = np.asarray(x, dtype=np.float64)
        x2 = x.reshape(-1, x.shape[-1]) if x.ndim > 1 else x[:, None]
        if x2.shape[0] == 0 or np.all(np.isnan(x2), axis=0).any():
            raise ValueError("MinMaxScaler.fit needs at least one finite value per column")
        self.min_: NDArray[np.float64] = np.nanmin(x2, axis=0)
        self.max_: NDArray[np.float64] = np.nanmax(x2, axis=0)
        span = self.max_ - self.min_
        self.scale_: NDArray[np.float64] = np.where(span > 0, span, 1.0)
        return self

    def _check(self) -> None:
        if not hasattr(self, "min_"):
            raise RuntimeError("MinMaxScaler is not fitted; call fit() on training data first")

    def transform(self, x: np.ndarray) -> np.ndarray:
        self._check()
        return (np.asarray(x, dtype=np.float64) - self.min_) / self.scale_

    def inverse_transform(self, x: np.ndarray) -> np.ndarray:
        self._check()
        return np.asarray(x, dtype=np.float64) * self.scale_ + self.min_

    def fit_transform(self, x: np.ndarray) -> np.ndarray:
        return self.fit(x).transform(x)

    def to_dict(self) -> dict[str, Any]:
        """Plain lists, for safe (non-pickle) serialisation."""
        self._check()
        return {"min": self.min_.tolist(), "max": self.max_.tolist()}

    @classmethod
    def from_dict(cls, state: dict[str, Any]) -> MinMaxScaler:
        """The inverse of :meth:`to_dict`; ``ValueError`` unless ``min`` and ``max`` are lists
        of finite numbers of one length with ``max >= min`` (a model file is untrusted)."""
        if not isinstance(state, dict) or set(state) != {"min", "max"}:
            raise ValueError("a scaler holds exactly the fields min and max")
        for key in ("min", "max"):
            values = state[key]
            if (
                not isinstance(values, list)
                or not values
                or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in values)
            ):
                raise ValueError(f"scaler {key} is not a non-empty list of numbers")
        scaler = cls()
        scaler.min_ = np.asarray(state["min"], dtype=np.float64)
        scaler.max_ = np.asarray(state["max"], dtype=np.float64)
        if scaler.min_.shape != scaler.max_.shape:
            raise ValueError("scaler min and max differ in length")
        if not (np.isfinite(scaler.min_).all() and np.isfinite(scaler.max_).all()):
            raise ValueError("scaler min or max is not finite")
        if (scaler.max_ < scaler.min_).any():
            raise ValueError("scaler max is below its min (the range must be >= 0)")
        span = scaler.max_ - scaler.min_
        scaler.scale_ = np.where(span > 0, span, 1.0)
        return scaler
