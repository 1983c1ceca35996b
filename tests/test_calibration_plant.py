"""Calibration on the plant emulator: a machine calibrated on a start-up and a steady record
is compared with its true parameters (the plant's draws and thermal state), and the calibrated
physics with the nominal one on a separate speed-change record of the same machine."""

import math

import numpy as np
import pytest

from drafttwin import ROLLERS
from drafttwin.calibration import calibrate
from drafttwin.data.io import read_measurements
from drafttwin.mechanics import DriveTrain, reduce, simulate
from drafttwin.plant import Machine, Plant

SEED = 7  # a validation machine (the benchmark reports on 101-103)
SECONDS = 30.0


def _rotor_factor(plant: Plant, t_s: float) -> float:
    th = plant.config.thermal
    warm = th.warmup_kelvin * (1 - math.exp(-(t_s + th.elapsed_at_start_s) / th.time_constant_s))
    return 1.0 + th.resistance_per_kelvin * warm


@pytest.fixture(scope="module")
def records(tmp_path_factory):
    plant = Plant()
    machine = Machine.draw(plant.train, plant.config, SEED)
    folder = tmp_path_factory.mktemp("plant")
    paths, recs = {}, {}
    for k, scenario in enumerate(("startup", "steady", "speed-change"), start=1):
        rec = plant.run(SECONDS, 100.0, seed=10 * SEED + k, scenario=scenario, machine=machine)
        paths[scenario], recs[scenario] = rec.write(folder / f"{scenario}.parquet")[0], rec
    data = read_measurements([paths["startup"], paths["steady"]])
    return plant, machine, data, recs["speed-change"]


@pytest.fixture(scope="module")
def case(records):
    plant, machine, data, test = records
    cal = calibrate(plant.train, data, model=reduce, model_name="reduced")
    return plant, machine, cal, test


@pytest.fixture(scope="module")
def wander(records):
    plant, machine, data, _ = records
    cal = calibrate(plant.train, data, model=reduce, model_name="reduced",
                    coloured=("motor",))  # fmt: skip
    return plant, machine, cal


@pytest.mark.slow
def test_identified_parameters_lie_within_three_standard_errors_of_the_machine(case):
    plant, machine, cal, _ = case
    truth = {name: 1.0 + u for name, u in machine.draws.items()}
    truth["motor.rated_slip"] = _rotor_factor(plant, 0.5 * SECONDS)  # thermal state, mid-record
    identified = [e for e in cal.estimates if e.verdict == "identified"]
    assert len(identified) >= 2, [(e.name, e.verdict) for e in cal.estimates]
    for e in identified:
        assert abs(e.factor - truth[e.name]) <= 3 * e.factor_se, (e.name, e.factor, e.factor_se)
        assert 0 < e.factor_se <= 0.1 * e.factor  # the identifiability rule
    # stiffnesses do not show in 0.1 s block means of a reduced model: nominal, and said so
    stiff = [e for e in cal.estimates if e.name.startswith(("gear.", "shaft.", "chain."))]
    assert stiff and all(e.verdict == "not from this data" and e.factor == 1.0 for e in stiff)
    # the motor's breakdown torque acts as its slip with a small share: left nominal, noted
    breakdown = next(e for e in cal.estimates if e.name == "motor.breakdown_torque_ratio")
    assert breakdown.factor == 1.0 and breakdown.verdict == "not separable in this data"
    assert any("motor.breakdown_torque_ratio" in note for note in cal.notes)


@pytest.mark.slow
def test_the_supply_wander_model_finds_the_plants_jitter_and_keeps_the_truth_within_3_se(wander):
    plant, machine, cal = wander
    truth = {name: 1.0 + u for name, u in machine.draws.items()}
    truth["motor.rated_slip"] = _rotor_factor(plant, 0.5 * SECONDS)
    identified = [e for e in cal.estimates if e.verdict == "identified"]
    assert len(identified) >= 2, [(e.name, e.verdict) for e in cal.estimates]
    for e in identified:
        assert abs(e.factor - truth[e.name]) <= 3 * e.factor_se, (e.name, e.factor, e.factor_se)
    # the plant's VFD jitter (OU, sd jitter_hz, correlation_s) at the motor: 120 / poles rpm
    # per Hz, less the slip; estimated from two 30 s records, so only roughly
    motor = cal.residual_model["motor"]
    expected = plant.config.supply.jitter_hz * 120.0 / plant.train.spec.motor.poles
    assert 0.5 * expected < motor["wander_sd"] < 2.0 * expected, (motor, expected)
    assert 0.3 * plant.config.supply.correlation_s < motor["correlation_s"] < 30.0
    assert set(cal.residual_model) == {"motor"}
    assert "residual_model" in cal.to_dict()
    # the steady level the two records pin against the wander: about a record mean's spread
    # over sqrt(2) (GLS is little better than the plain mean for a level), and a new minute's
    # own mean moves by the OU formula for 60 s
    from drafttwin.calibration.noise import ChannelNoise, mean_sd

    model = ChannelNoise(motor["white_sd"] ** 2, motor["wander_sd"] ** 2, motor["correlation_s"])
    scored = SECONDS - 1.5  # the start-up stands still for 1 s; 0.5 s after the start not scored
    expected_level = math.hypot(mean_sd(model, scored, 0.1), mean_sd(model, SECONDS, 0.1)) / 2
    assert motor["level_sd"] == pytest.approx(expected_level, rel=0.15)
    assert motor["mean_sd_60s"] == pytest.approx(mean_sd(model, 60.0, 0.1), rel=1e-9)
    assert motor["mean_sd_60s"] < motor["wander_sd"]


@pytest.mark.slow
def test_calibrated_physics_beats_the_nominal_on_another_record(case):
    plant, _, cal, test = case
    assert all(abs(cal.bias_after[c]) < abs(cal.bias_before[c]) for c in cal.channels)

    series, good = test.series, ~(test.outlier | test.missing)  # the samples evaluate scores

    def bias(train: DriveTrain) -> np.ndarray:
        res = simulate(reduce(train), time_s=series.time_s, inputs=series.inputs)
        sim = res.channels(ROLLERS)
        return np.array([np.mean((sim - series.values)[good[:, j], j]) for j in range(4)])

    nominal, calibrated = np.abs(bias(plant.train)), np.abs(bias(cal.train))
    assert (calibrated < nominal).all(), (nominal, calibrated)
    assert calibrated[0] < 0.5 * nominal[0]


def test_cli_models_the_wander_by_default_only_where_a_motor_speed_is_recorded(tmp_path):
    import json

    from typer.testing import CliRunner

    from drafttwin.cli import app

    plant = Plant()
    machine = Machine.draw(plant.train, plant.config, SEED)
    path = plant.run(10.0, 100.0, seed=1, scenario="steady", machine=machine).write(
        tmp_path / "steady.parquet"
    )[0]
    without_motor = tmp_path / "rollers.csv"
    frame = __import__("pandas").read_parquet(path)
    frame.drop(columns=["motor"]).to_csv(without_motor, index=False)
    runner = CliRunner()
    weighting = {}
    for name, data, extra in (("default", path, []), ("off", path, ["--no-wander"]),
                              ("no motor", without_motor, [])):  # fmt: skip
        result = runner.invoke(app, ["calibrate", "--preset", "fa320a", "--data", str(data),
                                     "--params", "motor.rated_slip", "--json",
                                     "--out", str(tmp_path / f"{len(weighting)}.toml"), *extra])  # fmt: skip
        assert result.exit_code == 0, result.output
        report = json.loads(result.output)
        weighting[name] = (report["weighting"], "residual_model" in report)
    assert weighting["default"] == ("generalised least squares, white noise + wander on motor",
                                    True)  # fmt: skip
    assert weighting["off"] == weighting["no motor"] == ("least squares", False)
    refused = tmp_path / "refused.toml"
    result = runner.invoke(app, ["calibrate", "--preset", "fa320a", "--data", str(without_motor),
                                 "--wander", "--out", str(refused)])  # fmt: skip
    assert result.exit_code == 2 and "rollers.csv" in result.output and "motor" in result.output
    assert "Traceback" not in result.output and not refused.exists()
