"""Calibration: parameter registry, identifiability arithmetic, recovery of known parameters,
the calibrated train as TOML, and the CLI's refusals."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.signal import lfilter
from typer.testing import CliRunner

from drafttwin.calibration import calibrate, parameters, select, with_factors
from drafttwin.calibration import identify as I
from drafttwin.calibration.fit import block_means
from drafttwin.calibration.io import write_train
from drafttwin.cli import app
from drafttwin.data.io import read_measurements
from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import ConfigError
from drafttwin.mechanics import DriveTrain, simulate

BELT = Path(__file__).resolve().parents[1] / "docs" / "examples" / "belt_drive.toml"
CHANNELS = {"outputs": ["y"], "inputs": ["u"], "units": {"y": "rad/s", "u": "V"},
            "time_column": "t"}  # fmt: skip
TRUE = {"motor.rated_slip": 1.08, "bearing.flywheel": 1.25}


@pytest.fixture(scope="module")
def belt() -> DriveTrain:
    return DriveTrain.from_toml(BELT)


def _record(train: DriveTrain, seed: int, duration_s: float = 8.0) -> pd.DataFrame:
    """The belt drive's speed under a stepped set-point, with logger noise (0.02 rad/s)."""
    rng = np.random.default_rng(seed)
    t = np.round(np.arange(1, int(duration_s * 100) + 1) * 0.01, 10)
    levels = rng.uniform(4.0, 9.0, size=int(duration_s // 2) + 1)
    u = levels[(t // 2).astype(int)]
    y = simulate(train, time_s=t, inputs={"u": u}).channels()[:, 0]
    return pd.DataFrame({"t": t, "u": u, "y": y + 0.02 * rng.standard_normal(len(t))})


@pytest.fixture(scope="module")
def records(belt, tmp_path_factory) -> Path:
    names = list(TRUE)
    true_train = with_factors(belt, select(belt, names), [TRUE[n] for n in names])
    folder = tmp_path_factory.mktemp("belt")
    frame = pd.concat([_record(true_train, s).assign(record=s) for s in (1, 2)])
    frame.to_csv(folder / "train.csv", index=False)
    return folder / "train.csv"


def test_registry_names_match_the_plant_sidecar(belt):
    from drafttwin.plant.config import PlantConfig
    from drafttwin.plant.effects import true_train

    fa = DriveTrain.preset("fa320a")
    _, draws = true_train(fa, PlantConfig(), np.random.default_rng(0))
    assert set(draws) <= set(parameters(fa))  # every drawn parameter can be calibrated
    with pytest.raises(ConfigError, match="unknown parameter"):
        select(belt, ["roller.front.friction_coefficient"])


def test_factors_move_the_declared_values_and_only_those(belt):
    chosen = select(belt, ["motor.rated_slip", "bearing.flywheel", "belt.v_belt.axial_rigidity_n"])
    moved = with_factors(belt, chosen, [1.1, 2.0, 0.5]).to_dict()
    raw = belt.to_dict()
    assert moved["belt"][0]["axial_rigidity_n"] == pytest.approx(
        0.5 * raw["belt"][0]["axial_rigidity_n"]
    )
    slip = lambda m: 1 - m["rated_rpm"] / (120 * m["rated_supply_hz"] / m["poles"])  # noqa: E731
    assert slip(moved["motor"]) == pytest.approx(1.1 * slip(raw["motor"]))
    # every bearing on the node: the example's 2-N m process load is its second one, which
    # a calibration could not reach when the first bearing alone carried the name
    flywheel = [(b, r) for b, r in zip(moved["bearing"], raw["bearing"], strict=True)
                if b["node"] == "flywheel"]  # fmt: skip
    assert len(flywheel) == 2
    for b, r in flywheel:
        assert b["coulomb_torque_nm"] == pytest.approx(2 * r["coulomb_torque_nm"])
        assert b.get("viscous_nms", 0.0) == pytest.approx(2 * r.get("viscous_nms", 0.0))
    assert moved["bearing"][0] == raw["bearing"][0]  # the motor's bearing stays
    assert moved["inertia"] == raw["inertia"]


def test_the_fit_stays_inside_the_values_each_declaration_accepts(belt):
    """Every factor was bounded to (0.2, 5) whatever its field's range: a fit could reach a
    breakdown torque ratio of 0.75 and stop with the declaration's validation error."""
    from drafttwin.calibration.fit import BOUNDS, Objective

    chosen = select(belt, ["motor.breakdown_torque_ratio", "motor.rated_slip",
                           "bearing.flywheel", "belt.v_belt.axial_rigidity_n"])  # fmt: skip
    # rigidity acts against the load: it moves as 1 / x in their common entry
    objective = Objective(belt, None, chosen, [[0], [1], [2, 3]], powers={3: -1.0})  # type: ignore[arg-type]
    low, high = objective.bounds()
    ratio = 2.6  # the example's breakdown torque ratio: valid in (1, 6]
    assert low[0] == pytest.approx(1.0 / ratio, rel=1e-5) and high[0] == pytest.approx(6 / ratio)
    slip = 1 - 1400 / 1500  # valid in (0, 1): 1 / slip = 15 > 5
    assert (low[1], high[1]) == pytest.approx((BOUNDS[0], min(BOUNDS[1], 1 / slip)))
    assert (low[2], high[2]) == pytest.approx(BOUNDS)  # 1 / x of (0.2, 5) is (0.2, 5)
    for x in (low, high):  # each corner of the box is a train the declaration accepts
        moved = with_factors(belt, chosen, objective.factors(x))
        assert moved.to_dict()["motor"]["breakdown_torque_ratio"] > 1.0
    with pytest.raises(ConfigError, match="breakdown_torque_ratio"):
        with_factors(belt, chosen, objective.factors(low * [0.999, 1, 1]))


def test_standard_errors_equal_the_textbook_formula():
    rng = np.random.default_rng(0)
    jac = rng.standard_normal((200, 3))
    res = rng.standard_normal(200)
    cov = np.linalg.inv(jac.T @ jac) * (res @ res) / (200 - 3)
    np.testing.assert_allclose(I.standard_errors(jac, res), np.sqrt(np.diag(cov)), rtol=1e-10)


def test_parallel_columns_are_one_combination_and_collinearity_sees_it():
    rng = np.random.default_rng(1)
    a, b = rng.standard_normal((2, 300))
    jac = np.column_stack([a, 3 * a + 1e-4 * b, b])
    assert sorted(map(sorted, I.combine(jac, [0, 1, 2]))) == [[0, 1], [2]]
    assert I.collinearity(jac) > 100 and I.collinearity(jac[:, [0, 2]]) < 2


def test_precision_not_the_collinearity_index_decides_what_is_identified():
    # two near-collinear columns (index ~40, as slip, belt and load on 180 s of plant records)
    # estimated from many rows: precise, so both identified; the same design from few rows is
    # not; a numerically dependent pair is refused however many rows there are
    rng = np.random.default_rng(2)
    a, b = rng.standard_normal((2, 20000))
    jac = np.column_stack([a, a + 0.035 * b])
    gamma = I.collinearity(jac)
    assert 30 < gamma < 60
    for rows, kept in ((20000, True), (20, False)):
        noise = rng.standard_normal(rows) * 0.05
        se = I.standard_errors(jac[:rows], noise)
        assert (I.least_determined(se / 1.0, gamma) is None) is kept, (rows, se)
    dependent = np.column_stack([a, a + 1e-5 * b])
    se = I.standard_errors(dependent, 1e-9 * rng.standard_normal(20000))
    assert I.collinearity(dependent) > I.MAX_COLLINEARITY
    assert I.least_determined(se, I.collinearity(dependent)) is not None


def test_whitening_removes_the_colour_of_an_ar_process():
    rng = np.random.default_rng(2)
    e = rng.standard_normal(4000)
    x = np.zeros_like(e)
    for k in range(1, len(e)):
        x[k] = 0.9 * x[k - 1] + e[k]
    white = I.ar_whitener(x[:, None], [(0, len(x))])(x[:, None])[:, 0]
    lag1 = lambda v: np.corrcoef(v[1:], v[:-1])[0, 1]  # noqa: E731
    assert lag1(x) > 0.85 and abs(lag1(white[20:])) < 0.05


def test_sandwich_errors_of_a_mean_match_the_long_run_variance_of_ar1_noise():
    """The OLS mean of AR(1) noise x_k = a x_(k-1) + e_k has variance s2 / (1 - a)^2 / n for
    large n (the long-run variance); the white-noise formula is too small by sqrt((1+a)/(1-a)).
    Two records of one channel, each filtered on its own."""
    rng = np.random.default_rng(3)
    a, n = 0.8, 20000
    x = np.concatenate([lfilter([1.0], [1.0, -a], rng.standard_normal(n)) for _ in range(2)])
    jac, mask = np.ones((2 * n, 1)), np.ones((2 * n, 1), bool)
    resid = x - x.mean()
    se = I.sandwich_standard_errors(jac, resid, mask, [(0, n), (n, 2 * n)])[0]
    expected = 1.0 / (1.0 - a) / np.sqrt(2 * n)
    assert se == pytest.approx(expected, rel=0.08)
    naive = I.standard_errors(jac, resid)[0]
    assert se / naive == pytest.approx(np.sqrt((1 + a) / (1 - a)), rel=0.1)
    # white residuals: the sandwich agrees with the textbook formula
    white = rng.standard_normal(n)
    both = [I.sandwich_standard_errors(np.ones((n, 1)), white, np.ones((n, 1), bool), [(0, n)]),
            I.standard_errors(np.ones((n, 1)), white)]  # fmt: skip
    assert both[0][0] == pytest.approx(both[1][0], rel=0.05)


def test_a_weak_member_of_a_combination_is_absorbed_by_the_strong_one():
    rng = np.random.default_rng(4)
    a, b = rng.standard_normal((2, 300))
    jac = np.column_stack([a, 0.05 * a, b, 0.5 * b])
    assert I.absorbed(jac, [0, 1]) == ([0], [1])
    assert I.absorbed(jac, [2, 3]) == ([2, 3], [])


def test_a_member_acting_against_its_combination_moves_inversely():
    """Belt rigidity speeds the rollers up where every load slows them: in one combination
    it must move as 1 / factor, or the members' effects would cancel."""
    from types import SimpleNamespace

    from drafttwin.calibration.fit import Objective
    from drafttwin.calibration.stages import _screen

    rng = np.random.default_rng(6)
    a, b = rng.standard_normal((2, 300)) * 10
    jac = np.column_stack([a, -0.5 * a, b])
    chosen = [SimpleNamespace(name=n) for n in ("load", "belt", "other")]
    free, verdicts, powers = _screen(jac, chosen, [])  # type: ignore[arg-type]
    assert sorted(map(sorted, free)) == [[0, 1], [2]] and powers == {1: -1.0} and not verdicts
    objective = Objective(None, None, [None] * 3, free, powers=powers)  # type: ignore[arg-type]
    factors = objective.factors([2.0, 1.5] if free[0] == [0, 1] else [1.5, 2.0])
    np.testing.assert_allclose(factors, [2.0, 0.5, 1.5])


def test_wild_blocks_are_set_aside_and_channels_weighted_by_their_residual_scale():
    from drafttwin.calibration.fit import Blocks, reweighted

    rng = np.random.default_rng(5)
    errors = np.column_stack([rng.standard_normal(400), 7.0 * rng.standard_normal(400)])
    errors[100, 0] = 600.0  # a spike the cleaning missed
    data = Blocks(None, ("a", "b"), {}, 10, np.zeros((400, 2)), [(0, 400)], np.ones(2))  # type: ignore[arg-type]
    out, wild = reweighted(data, errors)
    assert wild == 1 and np.isnan(out.measured[100, 0]) and np.isfinite(out.measured).sum() == 799
    kept = np.where(np.isfinite(out.measured), errors, np.nan)
    np.testing.assert_allclose(np.sqrt(np.nanmean(kept**2, axis=0)), out.noise, rtol=1e-12)
    assert out.noise[1] == pytest.approx(7.0, rel=0.1)


def test_a_motor_block_set_aside_takes_the_outputs_scored_against_it():
    """A steady supply leaves the motor's residual so tight that a start-up's blocks fall
    outside 10 robust deviations; the outputs scored relative to the motor there cannot be
    scored and must go too (they were NaN residuals that stopped the refit)."""
    from drafttwin.calibration.fit import Blocks, Objective, reweighted

    rng = np.random.default_rng(6)
    errors = rng.standard_normal((300, 3))
    errors[10:14, 2] = 400.0  # motor blocks far off
    gains = np.array([1.2, 0.0, 0.0])  # channel 0 scored against the motor, channel 1 not
    measured = np.full((300, 3), 100.0)
    data = Blocks(None, ("front", "aux", "motor"), {}, 10, measured, [(0, 300)], np.ones(3), gains)  # type: ignore[arg-type]
    out, wild = reweighted(data, errors)
    assert wild == 4
    assert np.isnan(out.measured[10:14, [0, 2]]).all() and np.isfinite(out.measured[10:14, 1]).all()
    assert np.isfinite(out.measured).sum() == 900 - 8
    objective = Objective(None, out, [], [])  # type: ignore[arg-type]
    objective._cache[()] = measured + 0.5
    residuals = objective.residuals([])
    assert residuals.size == 892 and np.isfinite(residuals).all()


def test_block_means_drop_sparse_blocks():
    v = np.arange(10.0)[:, None]
    v[5:9] = np.nan
    out = block_means(v, 5)
    np.testing.assert_allclose(out[:, 0], [2.0, np.nan])
    # a block longer than the record: no block (was a reshape error, a traceback in the CLI)
    assert block_means(np.ones((10, 3)), 11).shape == (0, 3)


def test_known_parameters_recovered_within_three_standard_errors(belt, records):
    data = read_measurements(records, **CHANNELS)
    names = [*TRUE, "belt.v_belt.damping_ratio"]
    cal = calibrate(belt, data, names)
    by = {e.name: e for e in cal.estimates}
    for name, factor in TRUE.items():
        e = by[name]
        assert e.verdict == "identified", (name, e)
        assert abs(e.factor - factor) <= 3 * e.factor_se, (name, e.factor, e.factor_se)
        assert e.factor_se < 0.02
    assert by["belt.v_belt.damping_ratio"].verdict == "not from this data"
    assert by["belt.v_belt.damping_ratio"].factor == 1.0  # left at nominal
    assert cal.rmse_after["y"] < 0.5 * cal.rmse_before["y"]
    assert abs(cal.bias_after["y"]) < 0.01 < abs(cal.bias_before["y"])


def test_calibrated_train_round_trips_through_toml(belt, tmp_path):
    chosen = select(belt, list(TRUE))
    moved = with_factors(belt, chosen, [1.08, 1.25])
    path = write_train(moved, tmp_path / "cal.toml", "calibrated\non test data")
    assert path.read_text().startswith("# calibrated\n# on test data\n")
    assert DriveTrain.from_toml(path).to_dict() == moved.to_dict()


def test_cli_writes_train_and_report_and_refuses_bad_requests(records, tmp_path):
    runner = CliRunner()
    common = ["calibrate", "--config", str(BELT), "--data", str(records), "--outputs", "y",
              "--inputs", "u", "--units", "y=rad/s,u=V", "--time-column", "t"]  # fmt: skip
    out = tmp_path / "cal.toml"
    sidecar = tmp_path / "cal.json"  # a plant record cal.csv's sidecar: not calibrate's to write
    sidecar.write_text('{"files": {"truth": "cal.truth.csv"}}')
    result = runner.invoke(app, [*common, "--params", "motor.rated_slip,bearing.flywheel",
                                 "--out", str(out), "--json"])  # fmt: skip
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    assert {"parameters", "rmse_before", "rmse_after"} <= set(report)
    assert {"name", "nominal", "estimate", "std_error", "identifiable"} <= set(
        report["parameters"][0]
    )
    assert report["rmse_after"] < report["rmse_before"]
    written = json.loads((tmp_path / "cal.calibration.json").read_text())
    assert written["parameters"] == report["parameters"]
    assert sidecar.read_text() == '{"files": {"truth": "cal.truth.csv"}}'  # left intact
    calibrated = DriveTrain.from_toml(out)
    slip = next(p for p in report["parameters"] if p["name"] == "motor.rated_slip")
    m = calibrated.to_dict()["motor"]
    assert 1 - m["rated_rpm"] / (120 * m["rated_supply_hz"] / m["poles"]) == pytest.approx(
        slip["estimate"]
    )
    result = runner.invoke(app, [*common, "--params", "motor.rated_slip", "--lines", "--json",
                                 "--out", str(tmp_path / "lines.toml")])  # fmt: skip
    assert result.exit_code == 0, result.output
    lines = json.loads(result.output)["lines"]
    assert set(lines["share_held_out"]) == {"y"} and lines["lines"][0]["name"].startswith(
        ("motor", "flywheel")
    )
    bad = tmp_path / "bad.toml"
    result = runner.invoke(app, [*common, "--params", "roller.front.friction_coefficient",
                                 "--out", str(bad)])  # fmt: skip
    assert result.exit_code == 2 and "unknown parameter" in result.output
    assert "Traceback" not in result.output and not bad.exists()
    result = runner.invoke(app, [*common, "--out", str(tmp_path / "cal.txt")])
    assert result.exit_code == 2 and "toml" in result.output
    taken = tmp_path / "taken.calibration.json"  # e.g. the sidecar of taken.calibration.csv
    taken.write_text("{}")
    result = runner.invoke(app, [*common, "--out", str(tmp_path / "taken.toml")])
    assert result.exit_code == 2 and "not a report of drafttwin calibrate" in result.output
    assert taken.read_text() == "{}" and not (tmp_path / "taken.toml").exists()


def test_supply_wander_cancels_from_the_scored_errors():
    """With a recorded motor speed, a common relative wander of motor and rollers (the VFD's
    frequency) leaves no scored error on the rollers; a roller's own error stays."""
    from drafttwin.calibration.fit import Blocks, motor_gains
    from drafttwin.mechanics import kinematics

    fa = DriveTrain.preset("fa320a")
    channels = ("front", "back", "motor")
    gains = motor_gains(fa, channels, {c: "rpm" for c in channels})
    kin = kinematics(fa)
    np.testing.assert_allclose(
        gains[:2], [kin.rollers[r].rpm / kin.motor_rpm for r in ("front", "back")], rtol=1e-12
    )
    assert gains[2] == 0.0
    speed = np.array([kin.rollers["front"].rpm, kin.rollers["back"].rpm, kin.motor_rpm])
    wander = 1.0 + 1e-3 * np.sin(np.arange(50) / 5.0)
    measured = speed[None, :] * wander[:, None]
    data = Blocks(None, channels, {}, 10, measured, [(0, 50)], np.ones(3), gains)  # type: ignore[arg-type]
    simulated = np.tile(speed, (50, 1))
    err = data.errors(simulated)
    assert np.abs(err[:, :2]).max() < 1e-9 and np.abs(err[:, 2]).max() > 1.0
    simulated[:, 1] += 0.5  # the back roller's own error is kept
    np.testing.assert_allclose(data.errors(simulated)[:, 1], 0.5, atol=1e-9)


def test_known_lines_merge_terms_of_one_frequency():
    from drafttwin.calibration.lines import known_lines

    fa = DriveTrain.preset("fa320a")
    names = [line.name for line in known_lines(fa)]
    # the front roller turns with its drive (a shaft), the rear shaft at half the main shaft's
    # speed (25/50 chain): speed data cannot tell these apart
    assert "front_drive x1 = front_roller x1" in names
    assert "main_shaft x1 = rear_shaft x2" in names
    assert any(n.startswith("mesh A-B") for n in names)


def test_known_line_recovered_from_angles_and_causal():
    """A once-per-revolution ripple of the back roller (0.3 rpm) in the measurement: the fit
    finds it on the held-out part, and the angle at a sample uses earlier samples only."""
    from drafttwin.calibration.lines import fit_lines, node_angles
    from drafttwin.mechanics import reduce, simulate

    fa = reduce(DriveTrain.preset("fa320a"))
    t = np.round(np.arange(1, 1501) * 0.01, 10)
    supply = {"supply_hz": np.full(len(t), 48.47)}
    sim = simulate(fa, time_s=t, inputs=supply)
    y = sim.roller_rpm()
    back = fa.node_index("back_roller")
    angle = np.cumsum(sim.node_rpm[:, back]) * 0.01 / 60.0 - 0.5 * sim.node_rpm[:, back] * 0.01 / 60
    rng = np.random.default_rng(4)
    y = y + 0.05 * rng.standard_normal(y.shape)
    y[:, 3] += 0.3 * np.sin(2 * np.pi * angle + 1.0)
    series = MeasurementSeries(t, y, inputs=supply)
    fit = fit_lines(DriveTrain.preset("fa320a"), series, fa)
    assert fit.share_held_out["back"] > 0.9 and abs(fit.share_held_out["front"]) < 0.05
    top = fit.to_dict(top=1)["lines"][0]
    assert top["name"].startswith("back_drive x1") and top["amplitude"]["back"] == pytest.approx(
        0.3, rel=0.05
    )
    changed = y.copy()
    changed[700:, :] += 50.0  # a different future must not move the angles before it
    later = node_angles(
        DriveTrain.preset("fa320a"), MeasurementSeries(t, changed, inputs=supply), sim
    )
    np.testing.assert_array_equal(
        later[:701], node_angles(DriveTrain.preset("fa320a"), series, sim)[:701]
    )


def test_a_train_file_gives_its_own_output_channels_and_units(records, tmp_path):
    """``--config`` with an ``[[output]]`` table: calibrate asked to map y onto the FA320A's
    front roller, then for y's unit; a --units the file contradicts ran in the wrong unit."""
    base = ["calibrate", "--config", str(BELT), "--data", str(records), "--params",
            "motor.rated_slip"]  # fmt: skip
    out = tmp_path / "own.toml"
    result = CliRunner().invoke(app, [*base, "--out", str(out), "--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    assert list(report["channels"]) == ["y"] and report["channels"]["y"]["unit"] == "rad/s"
    assert report["rmse_after"] < report["rmse_before"]
    wrong = tmp_path / "wrong.toml"
    result = CliRunner().invoke(app, [*base, "--units", "y=rpm", "--out", str(wrong)])
    assert result.exit_code == 2 and "y=rpm against the file's rad/s" in result.output
    assert "--units" in result.output and not wrong.exists()
