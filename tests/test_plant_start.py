"""How a recorded machine reached its set-point (issue 39, item 4: the healthy chimney).

The issue's healthy machine 4711 showed a sliver chimney at 1.18 cm: its third roller ran
1.4 % at half the rear chain's tooth frequency, a backlash mesh of the back rollers' branch
losing contact once every two teeth (period doubling). That state is one of two the gear
dynamics allow; the plant reached it by placing the machine at full speed with the static
deflections and every excitation switched on at once, which no machine does. A machine runs
up from rest along its VFD's ramp, and then none of these machines rattles
(``PlantConfig.start``, docs/plant.md).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from drafttwin.cli import app
from drafttwin.mechanics import DriveTrain
from drafttwin.plant import Machine, Plant, PlantConfig
from drafttwin.plant.live import LivePlant
from drafttwin.sliver.wavelengths import wavelength_table

RATE_HZ = 2000.0  # above twice the 362-Hz line
RUN_UP = PlantConfig()
PLACED = PlantConfig(start="operating-point")
RATTLERS = (4711, 5, 23)  # the machines of 39 that rattled from the operating point


@pytest.fixture(scope="module")
def half_tooth_hz() -> float:
    table = wavelength_table(DriveTrain.preset("fa320a"))
    return next(e.frequency_hz for e in table.elements if e.name == "rattle below rear_chain")


def _line_pct(rpm: np.ndarray, f0_hz: float) -> float:
    """Amplitude (% of the mean) of the strongest line within 3 % of ``f0_hz`` (Hann window)."""
    x = rpm - rpm.mean()
    w = np.hanning(len(x))
    amplitude = np.abs(np.fft.rfft(x * w)) * 2 / w.sum()
    f = np.fft.rfftfreq(len(x), 1 / RATE_HZ)
    band = np.abs(f / f0_hz - 1) < 0.03
    return float(100 * amplitude[band].max() / rpm.mean())


def _third_roller_line(config: PlantConfig, machine_seed: int, f0_hz: float) -> float:
    plant = Plant(config=config)
    machine = Machine.draw(plant.train, config, machine_seed)
    rec = plant.run(6.0, RATE_HZ, seed=1, machine=machine)
    return _line_pct(rec.true_rpm[-int(4 * RATE_HZ) :, 2], f0_hz)


def test_the_chain_tooth_rate_and_the_third_rollers_speed_agree(half_tooth_hz: float) -> None:
    # the rear chain's tooth frequency is 725 Hz at the FA320A's operating point
    assert 2 * half_tooth_hz == pytest.approx(725.0, rel=0.01)


@pytest.mark.parametrize("machine_seed", RATTLERS)
def test_a_machine_that_ran_up_does_not_rattle(machine_seed: int, half_tooth_hz: float) -> None:
    placed = _third_roller_line(PLACED, machine_seed, half_tooth_hz)
    ran_up = _third_roller_line(RUN_UP, machine_seed, half_tooth_hz)
    assert placed > 1.0  # the rattle: 1.4-1.6 % at half the chain's tooth frequency
    assert ran_up < 0.05


def test_the_live_plant_runs_up_too(half_tooth_hz: float) -> None:
    lines = {}
    for name, config in (("placed", PLACED), ("ran up", RUN_UP)):
        plant = LivePlant(seed=23, rate_hz=RATE_HZ, config=config)
        step, third = plant.stepper, plant.stepper.rollers["third"]
        rpm = np.array([step.step(step.supply_hz)[third] for _ in range(int(4 * RATE_HZ))])
        lines[name] = _line_pct(rpm, half_tooth_hz)
    assert lines["placed"] > 1.0 and lines["ran up"] < 0.05, lines


def test_a_run_up_ends_at_the_same_running_state() -> None:
    """The start changes the dynamic state a machine is in, not where it runs: the mean
    speeds of a machine that does not rattle agree to its encoders' resolution."""
    plant, placed_plant = Plant(config=RUN_UP), Plant(config=PLACED)
    machine = Machine.draw(plant.train, RUN_UP, 7)
    a = plant.run(4.0, 100.0, seed=3, machine=machine).true_rpm
    b = placed_plant.run(4.0, 100.0, seed=3, machine=machine).true_rpm
    np.testing.assert_allclose(a.mean(axis=0), b.mean(axis=0), rtol=2e-4)


def test_generate_takes_the_start_and_records_it(tmp_path: Path) -> None:
    runner = CliRunner()
    for start in ("run-up", "operating-point"):
        out = tmp_path / f"{start}.csv"
        res = runner.invoke(app, ["generate", "--duration", "0.5", "--start", start, "--quiet",
                                  "--out", str(out)])  # fmt: skip
        assert res.exit_code == 0, res.output
        assert json.loads(out.with_suffix(".json").read_text())["plant_config"]["start"] == start
    res = runner.invoke(app, ["generate", "--duration", "0.5", "--start", "rest",
                              "--out", str(tmp_path / "x.csv")])  # fmt: skip
    assert res.exit_code == 2
    assert "--start" in res.output and "operating-point or run-up" in res.output
    assert not list(tmp_path.glob("x.*"))


def _chimneys(tmp_path: Path, start: str, duration_s: str) -> list[dict]:
    """``generate --seed 32 --machine-seed 4711 --sliver`` (the issue's record), diagnosed."""
    runner = CliRunner()
    out = tmp_path / f"{start}.csv"
    res = runner.invoke(app, ["generate", "--duration", duration_s, "--seed", "32",
                              "--machine-seed", "4711", "--sliver", "--start", start,
                              "--quiet", "--out", str(out)])  # fmt: skip
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["sliver", "diagnose", "--data", str(out), "--json"])
    assert res.exit_code == 0, res.output
    return list(json.loads(res.output)["chimneys"])


def _at_rattle(chimneys: list[dict]) -> list[dict]:
    return [c for c in chimneys if abs(c["wavelength_m"] - 0.0118) < 0.001]


@pytest.mark.slow
def test_the_issues_machine_leaves_no_rattle_chimney(tmp_path: Path) -> None:
    """30 s of the issue's record (128 m): placed at the operating point its sliver shows the
    rattle's 1.18-cm chimney, run up it does not."""
    assert _at_rattle(_chimneys(tmp_path, "operating-point", "30"))
    assert not _at_rattle(_chimneys(tmp_path, "run-up", "30"))


@pytest.mark.long
def test_the_issues_healthy_record_shows_no_chimney(tmp_path: Path) -> None:
    """The issue's whole record (120 s, 513 m): no chimney at all."""
    assert _chimneys(tmp_path, "run-up", "120") == []
