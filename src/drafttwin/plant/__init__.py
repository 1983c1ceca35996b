"""The plant emulator: plays the FA320A drawing frame and its measurement chain.

from drafttwin.plant import Plant
rec = Plant().run(duration_s=60, rate_hz=100, seed=1)   # PlantRecording
rec.series            # measured MeasurementSeries (NaN = dropped sample)
rec.true_rpm          # what a perfect encoder would have reported
m = Machine.draw(Plant().train, PlantConfig(), seed=7)   # one machine, recorded twice:
a = Plant().run(60, seed=1, machine=m, scenario="startup")
b = Plant().run(60, seed=2, machine=m, scenario="speed-change")
"""

from drafttwin.plant.config import PlantConfig
from drafttwin.plant.emulator import Plant, PlantRecording
from drafttwin.plant.machine import Machine
from drafttwin.plant.scenarios import SCENARIOS

__all__ = ["SCENARIOS", "Machine", "Plant", "PlantConfig", "PlantRecording"]
