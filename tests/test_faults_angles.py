"""Roller angle lags: a worn mesh or an elongated chain makes the driven roller trail by a
fixed angle, which the cumulative encoder counts show and the physics ranking names."""

import math

import numpy as np
import pytest

from drafttwin.diagnosis.blocks import BlockStream
from drafttwin.diagnosis.locate import SignatureModel, rank_causes
from drafttwin.diagnosis.residuals import BlockFeatures, block_features, predicted_ratio
from drafttwin.mechanics import DriveTrain
from drafttwin.plant.config import Sensors
from drafttwin.plant.sensors import encoder_rpm

RPM = np.array([1815.65, 434.66, 426.12, 355.10, 1450.0])
TUNING_ROWS = 24_000  # 240 s at 100 Hz: two such records hold the lags' 400 tuning blocks
COUNTS = 10_000  # edges per revolution (2 500 ppr, quadrature)


def counted(step_mrad: float, at_s: float, n: int = 6000, seed: int = 0) -> np.ndarray:
    """Counted speeds of five channels at 100 Hz, the second roller's angle stepping back by
    ``step_mrad`` at ``at_s`` (spread over 0.1 s), with +-0.01 % common speed wander."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    wander = 1 + 1e-4 * np.sin(2 * np.pi * t / 37.0)
    true = RPM[None, :] * wander[:, None]
    ramp = np.clip((t - at_s) / 0.1, 0, 1)
    true[:, 1] -= (
        np.diff(np.concatenate([[0.0], ramp])) * step_mrad * 1e-3 / (2 * np.pi) * 60 / 0.01
    )
    return encoder_rpm(true, 0.01, Sensors(clock_jitter_s=0.0), rng), true


def lost_rows(y: np.ndarray, seed: int) -> np.ndarray:
    """Whole logger rows lost as the plant loses them: 0.2 % single rows and a burst of 30
    a minute."""
    rng = np.random.default_rng(seed)
    y = y.copy()
    y[rng.random(len(y)) < 0.002] = np.nan
    for start in rng.integers(0, len(y) - 40, size=1):
        y[start : start + 30] = np.nan
    return y


def test_lag_bridges_lost_rows_and_shows_a_step():
    t = np.arange(6000) * 0.01
    healthy, true = counted(0.0, 1e9)
    stepped, _ = counted(1.25, 30.0, seed=1)
    for y, step in ((healthy, 0.0), (stepped, -1.25)):
        f = block_features(lost_rows(y, 2), true, t, 1.0)
        lag = f.lag - f.lag[:20].mean(axis=0)
        assert lag.shape == (60, 3)
        # after the step: the second roller trails by it, to half an edge (0.63 mrad: a block
        # mean of counts keeps part of the quantisation, its phase moving with the speed);
        # the others stay put
        assert lag[35:, 0].mean() == pytest.approx(step, abs=0.3)
        assert np.abs(lag[:29]).max() < 0.3 and np.abs(lag[:, 1:]).max() < 0.3


def fed_in_pieces(y: np.ndarray, yhat: np.ndarray, t: np.ndarray, seed: int) -> BlockFeatures:
    """The features of rows pushed into a stream in pieces of 1-250 rows (as the live twin
    pushes its samples), the stream then finished."""
    rng = np.random.default_rng(seed)
    stream = BlockStream(1.0, float(np.median(np.diff(t))), predicted_ratio(yhat))
    rows, i = [], 0
    while i < len(t):
        k = int(rng.integers(1, 251))
        rows += stream.push(t[i : i + k], y[i : i + k], yhat[i : i + k])
        i += k
    return BlockFeatures.from_rows(rows + stream.finish(), stream.block_s)


def test_lags_fed_in_pieces_are_the_whole_records_bit_for_bit():
    """The live twin pushes rows as they come; the offline diagnosis a whole record. One
    implementation: lost rows at a block's edges are anchored with rows on both sides in
    either case, and the features are identical (before 2026-11-28 a second implementation
    fed block by block differed by up to 3.4 mrad on plant records)."""
    t = np.arange(6000) * 0.01
    y, true = counted(1.25, 30.0, seed=3)
    y = lost_rows(y, 4)
    for start in (1000, 1998, 2399, 3100, 5990):  # gaps at a block's start, across, at its end
        y[start : start + 3] = np.nan
    whole = block_features(y, true, t, 1.0)
    for seed in range(3):
        fed = fed_in_pieces(y, true, t, seed)
        assert np.array_equal(fed.lag, whole.lag)
        assert np.array_equal(fed.level, whole.level, equal_nan=True)
        assert np.array_equal(fed.lost, whole.lost) and np.array_equal(fed.run, whole.run)
        assert np.array_equal(fed.time_s, whole.time_s)


def test_a_gap_anchors_alike_wherever_the_stream_paused(monkeypatch):
    """The stream finalises rows up to the block's second-to-last row: a gap ending there
    must be anchored when the next block comes (once it was not: its lost counts stayed in
    the lag, and the synthetic false-alarm rate rose from 6 to 10 in 20 records). With moves
    ruled out (the only thing that depends on the rows seen so far), per-block feeding and
    one pass over the whole record give the same lags (to the sums' rounding; a missed
    anchor is a tenth of a mrad or more)."""
    from drafttwin.diagnosis import blocks

    monkeypatch.setattr(blocks, "MOVED", np.inf)
    y, true = counted(0.0, 1e9, 3000, 5)
    for start in (98, 297, 399, 500, 1097, 1199):  # gaps ending at each block's pause, across
        y[start : start + (2 if start % 100 == 97 else 1)] = np.nan
    good = np.isfinite(y)
    one = blocks.LagCounter(predicted_ratio(true), 0.01)
    whole = np.vstack([one.add(y[:, :4], good[:, :4]), one.finish()])
    fed = blocks.LagCounter(predicted_ratio(true), 0.01)
    parts = [fed.add(y[i : i + 100, :4], good[i : i + 100, :4]) for i in range(0, 3000, 100)]
    assert np.abs(np.vstack([*parts, fed.finish()]) - whole).max() < 1e-9


@pytest.fixture(scope="module")
def signatures():
    return SignatureModel(DriveTrain.preset("fa320a"))


def base_radius_m(gear: dict, teeth: int) -> float:
    return gear["module_mm"] * 1e-3 * teeth / 2 * math.cos(math.radians(gear["pressure_angle_deg"]))


def test_worn_mesh_trails_by_depth_over_base_radius(signatures):
    gears = {g["name"]: g for g in DriveTrain.preset("fa320a").to_dict()["gear"]}
    ef, cd = gears["E-F"], gears["C-D"]
    sig = signatures.signature("E-F", "wear", 60.0)
    assert np.abs(sig[:5]).max() < 1e-9  # no mean speed changes: a positive drive
    expected = -60e-6 / base_radius_m(ef, ef["driven_teeth"]) * 1e3  # mrad of the second roller
    assert sig[5] == pytest.approx(expected, rel=0.01) and sig[6] == sig[7] == 0
    # C-D wear: gear D trails, and the second roller by the ratio of E-F behind it
    sig = signatures.signature("C-D", "wear", 60.0)
    ratio = ef["driver_teeth"] / ef["driven_teeth"]
    assert sig[5] == pytest.approx(-60e-6 / base_radius_m(cd, cd["driven_teeth"]) * 1e3 * ratio,
                                   rel=0.01)  # fmt: skip
    # G-H wear: the back roller (H) and the third (driven from the same shaft) trail
    sig = signatures.signature("G-H", "wear", 60.0)
    assert sig[5] == 0 and sig[6] < 0 and sig[7] < 0
    # the model is linear in the depth (the ranking scales one run): a 150-um wear computed
    # directly from the static angles of the worn train
    from drafttwin.mechanics import static_angles

    train = DriveTrain.preset("fa320a")
    raw = train.to_dict()
    factor = 1 - min(0.5, 150 / (100 * ef["module_mm"]))
    raw["gear"] = [dict(g, backlash_um=g["backlash_um"] + 300,
                        mesh_stiffness_n_per_m=g["mesh_stiffness_n_per_m"] * factor)
                   if g["name"] == "E-F" else g for g in raw["gear"]]  # fmt: skip
    node = train.node_index("second_roller")
    direct = static_angles(DriveTrain.from_dict(raw))[node] - static_angles(train)[node]
    assert signatures.signature("E-F", "wear", 150.0)[5] == pytest.approx(1e3 * direct, rel=0.01)
    # a chain elongated by 1 %: half the extra loop at the rear sprocket, mrad, tens of them
    sig = signatures.signature("rear_chain", "elongation", 1.0)
    assert sig[5] == 0 and -40 < sig[7] < -10


def test_ranking_names_the_worn_mesh_not_an_encoder(signatures):
    cov = np.zeros((11, 11))
    cov[:5, :5] = (3e-5) ** 2 * np.ones((5, 5)) + np.diag([1e-6**2] * 4 + [3e-6**2])
    cov[5:, 5:] = 0.1**2 * (0.5 * np.eye(6) + 0.5)  # the two halves' lags, correlated
    signatures.elapsed_s = (8.0, 23.0)
    try:
        shift = signatures.signature("E-F", "wear", 60.0)
        causes = rank_causes(signatures, shift, cov)
        assert causes[0].name == "E-F:wear" and "C-D:wear" in causes[0].group
        assert causes[0].interval[0] <= 60 <= causes[0].interval[1]
        assert "second:gain" not in {c.name for c in causes[:2]}  # a gain's lag would grow
        gain = rank_causes(signatures, signatures.signature("second", "gain", 2e-4), cov)
        assert gain[0].name == "second:gain"
        assert gain[0].severity == pytest.approx(2e-4, rel=0.05)
        back = rank_causes(signatures, signatures.signature("G-H", "wear", 150.0), cov)
        assert {back[0].name, *back[0].group} >= {"G-H:wear", "rear_chain:elongation"}
    finally:
        signatures.elapsed_s = (0.0,)


@pytest.mark.long  # 7 min of full plant records; test_ranking_names_the_worn_mesh_not_an_encoder
def test_diagnose_names_the_worn_ef_mesh_on_plant_records():  # is its fast variant
    from drafttwin.diagnosis.detect import FaultDetector
    from drafttwin.diagnosis.diagnose import Diagnoser
    from drafttwin.diagnosis.residuals import record_features
    from drafttwin.plant import Machine, Plant
    from drafttwin.plant.faults import FaultSpec

    plant, train = Plant(), DriveTrain.preset("fa320a")
    machine = Machine.draw(plant.train, plant.config, 5)

    def record(seed, *faults, duration=30.0):
        return plant.run(duration, seed=seed, machine=machine,
                         faults=[FaultSpec.parse(f) for f in faults])  # fmt: skip

    # the lags are watched only when the tuning holds 400 decided blocks (a record outlasting
    # the reference window by the long-run variance's 60 blocks among them); shorter ones
    # leave them off (and say so)
    short = FaultDetector().fit([record_features(train, record(1).series)])
    assert not short.lags_watched and "at least 415 s" in (short.lags_note() or "")
    det = FaultDetector().fit([record_features(train, record(1, duration=420.0).series)])
    assert det.lags_watched and det.lags_note() is None
    dx = Diagnoser(train, det).diagnose(record(3, "E-F:wear:severity=150:onset=17").series)
    assert dx.alarm is not None and 17 <= dx.alarm.time_s < 21
    assert dx.alarm.test == "lag_second"
    assert dx.causes[0].name == "E-F:wear" and "C-D:wear" in dx.causes[0].group


def test_a_stuck_encoder_seen_first_by_a_cusum_is_named_not_a_machine_element():
    """A held value corrupts its channel's block level (and its counted angle) before its
    run is long enough for the stuck rule: in the benchmark a 1-s stuck back encoder from
    18.78 s moved the back roller's parity in block 18 (a run of 23 samples against a limit
    of 26) and the rule fired a block later, so the ranking blamed a machine element. The
    sensor rule in the alarm's window names the encoder instead."""
    from dataclasses import replace

    from drafttwin.diagnosis.detect import FaultDetector
    from drafttwin.diagnosis.diagnose import Diagnoser

    n = 10_000
    t = np.arange(n) * 0.01
    healthy = []
    for seed in (11, 12):
        y, true = counted(0.0, 1e9, n, seed)
        healthy.append(block_features(lost_rows(y, seed), true, t, 1.0))
    det = FaultDetector().fit(healthy)
    y, true = counted(0.0, 1e9, n, seed=13)
    f = block_features(y, true, t, 1.0)
    level, run, stale = f.level.copy(), f.run.copy(), f.stale_runs.copy()
    level[40:42, 3] += 4e-4  # the held value's block means
    run[41, 3] = 2 * det.run_limit_[3]  # the rule fires one block after the CUSUM
    stale[41, 3] = run[41, 3]  # a held value's run moves its lag
    f = replace(f, level=level, run=run, stale=stale)
    first = det.run(f).first
    assert first is not None and first.test == "parity_back" and first.block == 40
    dx = Diagnoser(DriveTrain.preset("fa320a"), det).from_features(f)
    assert dx.causes[0].name == "back:stuck" and dx.causes[0].family == "sensor"
    # without the stuck run the same shift is ranked as a machine or encoder-gain cause
    run[41, 3] = stale[41, 3] = 1
    dx = Diagnoser(DriveTrain.preset("fa320a"), det).from_features(replace(f, run=run,
                                                                        stale=stale))  # fmt: skip
    assert dx.causes and dx.causes[0].kind != "stuck"


def test_a_lag_step_alarms_in_its_block_by_the_jump_rule():
    """A worn mesh steps the lag at once. Whitened with a coefficient near its cap, the step
    is all in one block's innovation, which the CUSUM (widened for the lags' slow wander)
    need not reach; the one-block jump rule (twice the largest innovation in tuning) does."""
    from drafttwin.diagnosis.cusum import STREAMS
    from drafttwin.diagnosis.detect import FaultDetector

    def feats(step: float, seed: int, n: int = 10_000) -> object:
        y, true = counted(step, 50.0, n, seed)
        return block_features(lost_rows(y, seed), true, np.arange(n) * 0.01, 1.0)

    # the lags are watched with 400 decided blocks of tuning (2 x 225 here)
    det = FaultDetector().fit([feats(0.0, s, TUNING_ROWS) for s in (21, 22)])
    i = STREAMS.index("lag_second")
    assert det.jump_limit_[i] > 0 and not det.jump_limit_[: STREAMS.index("lag_second")].any()
    # these synthetic counts of a constant speed repeat one value through the step's 0.1-s
    # dip (6 samples against a healthy longest run of 2): the stuck rule is not under test
    det.run_limit_ = det.run_limit_ * 10
    assert det.run(feats(0.0, 23)).first is None
    first = det.run(feats(3.0, 24)).first
    assert first is not None and first.test == "lag_second" and first.direction == -1
    assert 50.0 <= first.time_s <= 51.5
    # the jump rule's alarm: the statistic it raised is not a CUSUM's (below h)
    det2 = FaultDetector().fit([feats(0.0, s, TUNING_ROWS) for s in (21, 22)])
    det2.run_limit_ = det2.run_limit_ * 10
    stat = det2.run(feats(3.0, 24)).statistic
    assert stat[int(first.block), i] < 1.0


def chain_slack_taken_up(step_mrad: float, at_s: float, n: int = 6000, seed: int = 0):
    """Counted speeds with the third and the back roller's angles stepping back together by
    ``step_mrad`` within 0.03 s (a rear chain's slack taken up: a dip of about 2.5 %)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    true = np.repeat(RPM[None, :], n, axis=0)
    ramp = np.clip((t - at_s) / 0.03, 0, 1)
    dip = np.diff(np.concatenate([[0.0], ramp])) * step_mrad * 1e-3 / (2 * np.pi) * 60 / 0.01
    physics = true.copy()  # the prediction has no slack: the dip is in the measurement only
    true[:, 2] -= dip
    true[:, 3] -= dip
    return encoder_rpm(true, 0.01, Sensors(clock_jitter_s=0.0), rng), physics


def test_a_transient_moving_two_rollers_is_counted_while_spikes_are_bridged():
    """A rear chain's elongation dips the third and the back roller together by ~2.5 % for
    2-3 samples: past the 1 % spike band, so the rows were bridged as spikes and the lag step
    (30 mrad here) vanished (no chain-elongation step was detected in the fault benchmark).
    Data-path spikes, one sample of one channel (or of two in one row), are still bridged."""
    t = np.arange(6000) * 0.01
    rng = np.random.default_rng(5)
    for step, at_s in ((30.0, 30.0), (0.0, 1e9), (30.0, 29.985)):  # last: across a block's edge
        y, true = chain_slack_taken_up(step, at_s, seed=6)
        rows = rng.choice(np.arange(100, 5900), size=12, replace=False)
        y[rows, rng.integers(0, 4, size=12)] *= 1.2  # single spikes, 20 %
        y[4500, 2:4] *= 0.8  # two channels spiking in one row
        f = block_features(y, true, t, 1.0)
        lag = f.lag - f.lag[:20].mean(axis=0)
        assert lag[35:, 1:].mean(axis=0) == pytest.approx([-step, -step], abs=0.5)
        assert np.abs(lag[:29]).max() < 0.5 and np.abs(lag[:, 0]).max() < 0.5
        fed = fed_in_pieces(y, true, t, 7).lag
        # the live twin, row by row, keeps the transient too (also across a block's edge)
        live = fed - fed[:20].mean(axis=0)
        assert live[35:, 1:].mean(axis=0) == pytest.approx([-step, -step], abs=0.5)
