"""The fault benchmark's learned residuals on synthetic records: the one-step data-driven
residual hides a persistent step (an innovation), the open-loop hybrid's keeps it."""

import json

import numpy as np
import pytest

from drafttwin.studies.faults.learned import LEARNED, LearnedResiduals

RATE_HZ, BASE = 100.0, np.array([1815.7, 434.7, 426.1, 355.1, 1450.0])  # rpm, fa320a


def _record(seed: int, level: float, step_at: float | None = None, step: float = 0.0,
            duration_s: float = 60.0) -> dict[str, np.ndarray]:  # fmt: skip
    rng = np.random.default_rng(seed)
    t = np.arange(int(duration_s * RATE_HZ)) / RATE_HZ
    scale = 1.0 + level + (np.zeros(len(t)) if step_at is None else step * (t >= step_at))
    y = BASE * scale[:, None] * (1.0 + 2e-4 * rng.standard_normal((len(t), 5)))
    physics = np.tile(BASE, (len(t), 1))
    return {"time_s": t, "y": y, "supply_hz": np.full(len(t), 48.47), "physics": physics}


@pytest.fixture(scope="module")
def fitted() -> LearnedResiduals:
    # healthy machines 1 % apart: the test record's levels lie inside the training range
    return LearnedResiduals(block_s=1.0, seed=0).fit([_record(1, 0.0), _record(2, 0.01)])


def test_one_step_residual_hides_a_step_the_hybrid_keeps(fitted):
    rec = _record(3, 0.0, step_at=30.0, step=0.005)
    shift = {}
    for method in LEARNED:
        f = fitted.features(method, rec)
        assert f.level.shape == (60, 5)
        before = np.nanmean(f.level[15:29], axis=0)
        after = np.nanmean(f.level[35:], axis=0)
        shift[method] = after - before
    np.testing.assert_allclose(shift["hybrid"], 0.005, atol=0.001)  # open loop: all of it
    assert np.all(np.abs(shift["data-driven"]) < 0.2 * 0.005)  # re-learned within its window


def test_describe_reports_both_fits(fitted):
    d = fitted.describe()
    for method in LEARNED:
        assert d[method]["fit_s"] > 0 and d[method]["epochs"] >= 1
    assert d["data-driven"]["task"] == "prediction" and d["hybrid"]["task"] == "simulation"
    # what the hybrid kept, as its folds chose it (JSON-able)
    assert d["hybrid"]["correction"]["kept"] in {"level", "offset", "none"}
    assert d["hybrid"]["correction"]["chosen_by"] == "validation folds"
    json.dumps(d)
    with pytest.raises(ValueError, match="unknown learned method"):
        fitted.prediction("persistence", _record(4, 0.0, duration_s=5.0))


def test_the_angle_lags_are_the_physics_not_the_networks(fitted):
    """The lags measure the gears' positive drive through the kinematic ratio: a network's
    predicted ratio is off by ~1e-4, which made the lag drift by mrad per second and the
    hybrid's ranking blame gear wear (benchmark, 2026-11-26). Both learned methods take the
    lags against the physics. (The hybrid, judged on validation folds, may keep no
    correction on these records and then predicts the physics itself: its own lags are the
    physics' and show nothing; the data-driven network's always drift.)"""
    from drafttwin.diagnosis.residuals import block_features

    rec = _record(4, 0.0)
    physics = block_features(rec["y"], rec["physics"], rec["time_s"], 1.0).lag
    for method in LEARNED:
        pred = fitted.prediction(method, rec)
        own = block_features(rec["y"], pred, rec["time_s"], 1.0).lag
        np.testing.assert_array_equal(fitted.features(method, rec).lag, physics)
        ok = np.isfinite(pred).all(axis=1)  # past the window's first rows
        corrected = not np.array_equal(pred[ok], rec["physics"][ok])
        if method == "data-driven" or corrected:  # a network's own lags would drift
            assert np.abs(own - physics).max() > np.abs(physics).max(), method


def test_steady_running_is_the_physics_not_the_networks(fitted):
    """Which blocks are steady running is what the set-point commands: the physics says it.
    A one-step network's prediction follows the measured spikes past the 1 % steady band,
    which cut the benchmark's healthy 630-s records into about 80 runs, each shorter than
    the reference window (2026-11-30: the data-driven column detected 5-10 %, its lags
    unwatched). Both learned methods take the physics' steady blocks."""
    from drafttwin.diagnosis.residuals import block_features

    rec = _record(5, 0.0)
    rec["y"][np.arange(150, 6000, 300), 0] *= 1.03  # a 3 % spike every 3 s on the front
    physics = block_features(rec["y"], rec["physics"], rec["time_s"], 1.0)
    assert physics.steady_blocks.all()
    own = block_features(rec["y"], fitted.prediction("data-driven", rec), rec["time_s"], 1.0)
    assert not own.steady_blocks.all()  # what the network's own prediction would say
    for method in LEARNED:
        f = fitted.features(method, rec, physics)
        np.testing.assert_array_equal(f.steady_blocks, physics.steady_blocks)
        assert len(f.steady_runs()) == 1
        np.testing.assert_array_equal(fitted.features(method, rec).steady, physics.steady)


def test_stale_runs_are_judged_by_the_physics_lags(fitted):
    """A run of repeated readings counts as stale when the angle lag moved during it; a
    network's own lags drift, so healthy repeats seemed to move them (2026-11-30: 3 stuck
    alarms on the second roller in one healthy 630-s record of the data-driven column).
    The learned methods' stale runs are the physics' (its lags' runs)."""
    from drafttwin.diagnosis.residuals import block_features

    rec = _record(6, 0.0)
    for start in range(200, 6000, 400):  # the second roller's reading held for 20 rows
        rec["y"][start : start + 20, 1] = rec["y"][start, 1]
    physics = block_features(rec["y"], rec["physics"], rec["time_s"], 1.0)
    own = block_features(rec["y"], fitted.prediction("data-driven", rec), rec["time_s"], 1.0)
    assert not np.array_equal(own.stale, physics.stale)  # judged by the drifting lags
    for method in LEARNED:
        np.testing.assert_array_equal(fitted.features(method, rec, physics).stale,
                                      physics.stale)  # fmt: skip
