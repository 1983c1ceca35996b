"""The EMPS benchmark: data checks, the physical model, leakage, and the CLI on a slice.

The EMPS files are not in the repository (licence unclear). Tests that need them take the
folder from ``$DRAFTTWIN_EMPS_DIR`` (``.ci/run`` sets it) and skip with a reason when it is
not set; the refusal tests use fake files and always run.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from drafttwin.cli import app
from drafttwin.datasets import emps as emps_data
from drafttwin.datasets.emps import TEST_FILE, TRAIN_FILE, find_data_dir, load_emps
from drafttwin.errors import DataError
from drafttwin.models import make_model
from drafttwin.studies.emps.physics import EmpsPhysics, rmse_mm


def _data_dir() -> Path | None:
    try:
        folder = find_data_dir()
    except DataError:
        return None
    return folder if all((folder / f).is_file() for f in emps_data.SHA256) else None


DATA = _data_dir()
needs_data = pytest.mark.skipif(
    DATA is None,
    reason="EMPS data not found: set DRAFTTWIN_EMPS_DIR to the folder with DATA_EMPS.mat and "
    "DATA_EMPS_PULSES.mat (not shipped: licence unclear)",
)


@pytest.fixture(scope="module")
def records():
    return load_emps(DATA)[:2]


# ----- data checks (always run) ------------------------------------------------------------
def test_missing_file_is_refused_with_its_name(tmp_path: Path) -> None:
    (tmp_path / TRAIN_FILE).write_bytes(b"not the original")
    with pytest.raises(DataError, match="SHA-256") as err:
        load_emps(tmp_path)
    assert TRAIN_FILE in str(err.value) and "restore the original" in str(err.value)
    with pytest.raises(DataError, match="file not found") as err:
        emps_data.verify_file(tmp_path / TEST_FILE)
    assert TEST_FILE in str(err.value)


def test_missing_folder_and_env_var_are_refused(tmp_path: Path, monkeypatch) -> None:
    with pytest.raises(DataError, match="folder not found"):
        find_data_dir(tmp_path / "nowhere")
    monkeypatch.setenv(emps_data.ENV_VAR, str(tmp_path / "nowhere"))
    with pytest.raises(DataError, match=emps_data.ENV_VAR):
        find_data_dir()
    monkeypatch.setenv(emps_data.ENV_VAR, str(tmp_path))
    assert find_data_dir() == tmp_path
    monkeypatch.delenv(emps_data.ENV_VAR)
    with pytest.raises(DataError, match="no folder of EMPS data was given") as err:
        find_data_dir()  # library code searches nowhere else
    assert emps_data.ENV_VAR in str(err.value) and "--data-dir" in str(err.value)


def test_cli_refuses_missing_data_with_exit_code_2(tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["benchmark", "emps", "--data-dir", str(tmp_path),
                                      "--out", str(tmp_path / "out"), "--quiet"])  # fmt: skip
    assert result.exit_code == 2
    assert "file not found" in result.output and TRAIN_FILE in result.output
    assert not (tmp_path / "out").exists()


# ----- with the data -----------------------------------------------------------------------
@needs_data
def test_altered_copy_is_refused(tmp_path: Path) -> None:
    for name in emps_data.SHA256:
        shutil.copy(DATA / name, tmp_path / name)
    raw = bytearray((tmp_path / TEST_FILE).read_bytes())
    raw[len(raw) // 2] ^= 0x01
    (tmp_path / TEST_FILE).write_bytes(bytes(raw))
    emps_data.verify_file(tmp_path / TRAIN_FILE)  # the untouched copy passes
    with pytest.raises(DataError, match="does not match the published") as err:
        load_emps(tmp_path)
    assert TEST_FILE in str(err.value)


def _rk4_reference(
    p: EmpsPhysics, vir: np.ndarray, q0: float, *, stage_hold: bool, sub: int = 10
) -> np.ndarray:
    """Independent RK4 with 10 sub-steps per 1 ms sample. ``stage_hold=False``: the force of
    sample k is held over the whole sample (the data set's reference computation);
    ``True``: the force is read at each RK4 stage's time, so the last stage of a sample
    already sees sample k+1 (what a zero-order-hold signal in a general ODE kernel does)."""

    def acc(v: float, force: float) -> float:
        friction = p.coulomb_n * math.tanh(v / p.speed_eps_m_per_s) + p.viscous_ns_per_m * v
        return (force - friction - p.offset_n) / p.mass_kg

    h, q, v = 1e-3 / sub, q0, 0.0
    out = [q0]
    for k in range(len(vir) - 1):
        f = p.gtau_n_per_v * vir[k]
        for j in range(sub):
            last = stage_hold and j == sub - 1
            f_end = p.gtau_n_per_v * vir[k + 1] if last else f
            k1v, k1q = acc(v, f), v
            k2v, k2q = acc(v + h / 2 * k1v, f), v + h / 2 * k1v
            k3v, k3q = acc(v + h / 2 * k2v, f), v + h / 2 * k2v
            k4v, k4q = acc(v + h * k3v, f_end), v + h * k3v
            q += h / 6 * (k1q + 2 * k2q + 2 * k3q + k4q)
            v += h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
        out.append(q)
    return np.array(out)


@needs_data
def test_physics_matches_an_independent_rk4_on_the_first_seconds(records) -> None:
    train, test = records
    p = EmpsPhysics()
    for rec in (train.head(2500), test.head(2500)):
        ours = p.simulate(rec.vir_v, rec.qm_m[0])
        same = _rk4_reference(p, rec.vir_v, rec.qm_m[0], stage_hold=True)
        np.testing.assert_allclose(ours, same, rtol=0, atol=1e-11)
        # the data set's convention (force held over the whole sample) differs by the last
        # stage of each sample (weight dt/6): micrometres after 2.5 s, nothing in the RMSE
        readme = _rk4_reference(p, rec.vir_v, rec.qm_m[0], stage_hold=False)
        assert np.max(np.abs(ours - readme)) < 1e-5
        assert rmse_mm(rec.qm_m, ours, 20) == pytest.approx(rmse_mm(rec.qm_m, readme, 20), rel=2e-3)


@needs_data
def test_physics_reproduces_the_published_test_rmse(records) -> None:
    train, test = records
    p = EmpsPhysics()
    test_rmse = rmse_mm(test.qm_m, p.simulate(test.vir_v, test.qm_m[0]), 20)
    assert test_rmse == pytest.approx(9.23, rel=0.05)
    assert test_rmse == pytest.approx(9.23, rel=0.005)  # in fact within 0.5 %
    assert rmse_mm(train.qm_m, p.simulate(train.vir_v, train.qm_m[0]), 20) == pytest.approx(
        6.75, rel=0.05
    )


@needs_data
def test_simulation_mode_ignores_test_outputs_after_the_window(records) -> None:
    train, test = records
    mech = EmpsPhysics().mechanistic()
    model = make_model("parallel", task="simulation", outputs=("qm",), inputs=("vir",),
                       init_samples=20, window=20, hidden=8, layers=1, epochs=1, stride=5,
                       quiet=True, device="cpu")  # fmt: skip
    model.fit(train.head(3000).series(), mech)
    series = test.head(1500).series()
    base = model.predict_values(series, mech)
    rng = np.random.default_rng(1)
    noisy = series.with_values(
        series.values + np.r_[np.zeros(20), rng.normal(0, 0.05, 1480)][:, None]
    )
    np.testing.assert_array_equal(model.predict_values(noisy, mech), base)
    # the physics itself is causal: a 20-sample record gives the first 20 rows of a long one
    np.testing.assert_allclose(mech.predict_values(noisy.slice(0, 20)),
                               mech.predict_values(series)[:20], rtol=1e-12, atol=0)  # fmt: skip


@needs_data
def test_benchmark_cli_end_to_end_on_a_slice(tmp_path: Path) -> None:
    out = tmp_path / "emps"
    args = ["benchmark", "emps", "--data-dir", str(DATA), "--out", str(out), "--seeds", "1",
            "--epochs", "1", "--max-samples", "1000", "--quiet", "--json",
            "--models", "mechanistic,persistence,gru,parallel,md-s-l",
            "--physics", "both"]  # fmt: skip
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    rows = json.loads(result.output)
    assert {(r["task"], r["model"]) for r in rows} == {
        (t, m) for t in ("simulation", "prediction")
        for m in ("mechanistic", "persistence", "gru", "parallel", "md-s-l")
    }  # fmt: skip
    assert all(r["n_nan"] == 0 and math.isfinite(r["rmse_mm_mean"]) for r in rows)
    physics = {(r["model"], r["physics"]) for r in rows if r["task"] == "simulation"}
    assert physics == {("persistence", None), ("gru", None)} | {
        (m, p) for m in ("mechanistic", "parallel", "md-s-l") for p in ("published", "refitted")
    }  # fmt: skip
    doc = json.loads((out / "emps_results.json").read_text())
    assert doc["protocol"]["max_samples"] == 1000
    refit = doc["physics_refit"]  # on the first 1000 training samples only
    assert refit["rmse_mm"] < refit["rmse_mm_initial"]
    assert refit["parameters"]["mass_kg"] != doc["physics"]["mass_kg"]  # published, kept
    page = (out / "emps_report.html").read_text()
    assert "data:image/png;base64," in page and "smoke test" in page
    assert "Every network trained 1 epoch(s) (--epochs)" in page  # it had not said so
    assert "physics only (refitted)" in page and "MD-S-L (refitted physics)" in page
    assert (out / "emps_predictions.csv").is_file()


def test_figure_of_one_task_says_the_other_was_not_run() -> None:
    """``--tasks simulation`` leaves the prediction axis empty: no matplotlib warning about a
    legend without artists (it reached the user's terminal), the axis says why it is empty."""
    import warnings

    from drafttwin.report.emps import figure_png
    from drafttwin.studies.emps.run import EmpsResult

    t = np.linspace(0.0, 1.0, 50)
    y = 0.1 * np.sin(t)
    result = EmpsResult({}, {("simulation", "mechanistic"): y + 0.001}, t, y)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        png = figure_png(result)
    assert png.startswith(b"\x89PNG")


def test_the_position_panel_names_the_free_runs_that_leave_it() -> None:
    """A GRU free run of 616 mm had been clipped without a word."""
    import numpy as np

    from drafttwin.report.emps import beyond
    from drafttwin.studies.emps.run import EmpsResult

    t = np.linspace(0, 1, 50)
    y = 0.1 * np.sin(t)
    traces = {("simulation", "gru"): y + 0.6, ("simulation", "mechanistic"): y,
              ("prediction", "gru"): y + 5.0, ("simulation", "persistence"): y + 9.0}  # fmt: skip
    result = EmpsResult({}, traces, t, y)
    span = (float(y.min()) * 1e3 - 30, float(y.max()) * 1e3 + 30)
    assert beyond(result, span) == ["GRU (black box)"]
