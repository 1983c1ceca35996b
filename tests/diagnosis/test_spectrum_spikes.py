"""The spectra of the diagnosis (its line evidence and the page's "spectrum after the change")
leave data-path spikes out, as the detection does: one wrong reading of +27 % in a window
lifted the front roller's whole spectrum tenfold over every line (a helper's hunt, seen on
a healthy plant record's page)."""

import numpy as np

from drafttwin.data.series import MeasurementSeries
from drafttwin.diagnosis.spectrum import line_and_floor, residual_samples, spectrum

RATE = 100.0
N = 3000
T = np.arange(N) / RATE
LINE_HZ, LINE = 12.5, 2e-3  # a 0.2 % line on the front roller


def _series(spike_rows: list[int], seed: int = 0) -> MeasurementSeries:
    rng = np.random.default_rng(seed)
    speeds = np.array([1800.0, 400.0, 380.0, 320.0, 1450.0])
    y = speeds * (1 + 2e-4 * rng.standard_normal((N, 5)))
    y[:, 0] *= 1 + LINE * np.sin(2 * np.pi * LINE_HZ * T)
    for row in spike_rows:
        y[row, 0] *= 1.27  # the plant's bit errors: 15-40 % of a row
    return MeasurementSeries(time_s=T, values=y[:, :4], motor_rpm=y[:, 4],
                             inputs={"supply_hz": np.full(N, 50.0)})  # fmt: skip


def test_a_spike_leaves_the_line_and_the_floor_as_they_were() -> None:
    clean = residual_samples(_series([]))
    spiked = residual_samples(_series([1234, 2500]))
    f, a = spectrum(spiked[:, 0], RATE)
    line, floor = line_and_floor(f, a, LINE_HZ)
    f0, a0 = spectrum(clean[:, 0], RATE)
    line0, floor0 = line_and_floor(f0, a0, LINE_HZ)
    assert abs(line - LINE) < 0.05 * LINE and abs(line - line0) < 0.01 * LINE
    assert floor < 1.5 * floor0  # a kept 27 % spike lifts it some hundredfold
    np.testing.assert_allclose(spiked[:, 1:], clean[:, 1:])  # the other channels untouched


def test_a_step_in_speed_is_no_spike() -> None:
    s = _series([])
    s.values[N // 2 :, 0] *= 1.2  # a real change of speed persists: kept whole
    r = residual_samples(s)
    assert r[N // 2 + 5, 0] - r[N // 2 - 5, 0] > 0.15
