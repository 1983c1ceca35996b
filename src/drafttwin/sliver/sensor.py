"""The drawframe's sliver sensors: the delivery funnel and the infeed scanning rollers.

Both are modelled as research/sliver.md section 5 recommends: the reading is gain x (mass +
a bulk error), averaged over the sensor's contact length (a boxcar), with a first-order lag
and white noise, sampled every ``pitch_mm`` of delivered sliver (sensors on drawframes are
clocked by length). Public figures for sampling pitch, resolution or noise were not found:
the defaults are assumptions, stated in docs/sliver.md.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.signal import lfilter

from drafttwin.errors import ConfigError
from drafttwin.sliver.record import Sliver


@dataclass(frozen=True)
class SliverSensor:
    """A mass-per-length sensor on the sliver.

    Attributes:
        averaging_mm: contact (averaging) length, mm.
        lag_mm: first-order lag expressed in delivered length, mm (0: none).
        noise: relative white noise of one reading (0.002 = 0.2 %).
        gain_error: relative gain error (a bulk or calibration error), 0 when calibrated.
        pitch_mm: delivered length between readings, mm.
    """

    averaging_mm: float = 5.0
    lag_mm: float = 2.0
    noise: float = 0.002
    gain_error: float = 0.0
    pitch_mm: float = 2.0

    def __post_init__(self) -> None:
        ok = (0 <= self.averaging_mm <= 1000 and 0 <= self.lag_mm <= 1000
              and 0 <= self.noise < 0.5 and abs(self.gain_error) < 0.5
              and 0.5 <= self.pitch_mm <= 1000)  # fmt: skip
        if not ok:
            raise ConfigError(f"sliver sensor {asdict(self)}", where="sliver sensor",
                              fix="averaging and lag 0-1000 mm, noise and gain error below "
                              "0.5, pitch 0.5-1000 mm")  # fmt: skip

    def read(self, sliver: Sliver, rng: np.random.Generator) -> Sliver:
        """The sensor's readings of ``sliver`` (its grid must be finer than the pitch)."""
        h_mm = sliver.step_m * 1e3
        every = max(1, int(round(self.pitch_mm / h_mm)))
        x = _boxcar(sliver.linear_density_ktex, max(1, int(round(self.averaging_mm / h_mm))))
        if self.lag_mm > 0:
            a = math.exp(-h_mm / self.lag_mm)
            x = lfilter([1 - a], [1.0, -a], x, zi=[a * x[0]])[0]
        x = x[every - 1 :: every] * (1.0 + self.gain_error)
        x = x * (1.0 + self.noise * rng.standard_normal(x.size))
        time = None if sliver.time_s is None else sliver.time_s[every - 1 :: every]
        start = sliver.start_m + (every - 1) * sliver.step_m + sliver.step_m / 2
        step = every * sliver.step_m
        return Sliver(x, step, start_m=start - step / 2, time_s=time, staple=sliver.staple,
                      fibre_scale=sliver.fibre_scale,
                      info={**sliver.info, "sensor": asdict(self)})  # fmt: skip


def _boxcar(x: np.ndarray, width: int) -> np.ndarray:
    """Trailing moving average over ``width`` samples (the first ones over what exists)."""
    if width <= 1:
        return x.copy()
    c = np.concatenate([[0.0], np.cumsum(x)])
    idx = np.arange(1, x.size + 1)
    lo = np.maximum(idx - width, 0)
    mean: np.ndarray = (c[idx] - c[lo]) / (idx - lo)
    return mean
