"""A machine's learned detector on top of a prior (diagnosis/learning.combine): two minutes
of running cannot measure a stream's dynamics, so the prior's stand; the machine's own noise
only widens a stream's SD."""

import numpy as np

from drafttwin.diagnosis.cusum import STREAMS
from drafttwin.diagnosis.detect import FaultDetector
from drafttwin.diagnosis.learning import combine
from drafttwin.diagnosis.residuals import BlockFeatures


def _records(n_blocks: int, records: int, seed: int, noise: float = 1.0) -> list[BlockFeatures]:
    """Healthy block features: the four rollers' levels share an AR(1) of coefficient 0.92
    (the fleet's slow supply wander), each channel adds white noise, the lags wander slowly."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(records):
        common = np.zeros(n_blocks)
        for t in range(1, n_blocks):
            common[t] = 0.92 * common[t - 1] + 4e-5 * rng.standard_normal()
        level = common[:, None] + noise * 2e-5 * rng.standard_normal((n_blocks, 5))
        lag = np.cumsum(0.05 * rng.standard_normal((n_blocks, 3)), axis=0)
        out.append(BlockFeatures(np.arange(1.0, n_blocks + 1), level, np.zeros((n_blocks, 5)),
                                 np.ones((n_blocks, 5)), 1.0, lag))  # fmt: skip
    return out


def _fit(records: list[BlockFeatures]) -> FaultDetector:
    return FaultDetector(far_per_day=1.0).fit(records)


def test_the_prior_keeps_its_dynamics_and_a_short_run_cannot_narrow_a_stream():
    prior = _fit(_records(630, 12, seed=1))
    own = _fit(_records(135, 1, seed=2))  # 120 s past a 15-s reference window
    rollers = STREAMS.index("rollers")
    # two minutes underestimate the rollers' coefficient (the bias the live benchmark met)
    assert own.phi_[rollers] < prior.phi_[rollers] - 0.05
    out = combine(own, prior)
    watched = prior.watched_
    np.testing.assert_array_equal(out.phi_[watched], prior.phi_[watched])
    np.testing.assert_array_equal(out.long_run_[watched], prior.long_run_[watched])
    np.testing.assert_array_equal(out.sigma_[watched],
                                  np.maximum(own.sigma_, prior.sigma_)[watched])  # fmt: skip
    scale = {d: d.sigma_ * np.sqrt((1 - d.phi_**2) * d.long_run_) for d in (out, prior)}
    assert (scale[out] >= scale[prior] * (1 - 1e-12)).all()  # never less conservative


def test_a_machine_noisier_than_the_fleet_is_judged_by_its_own_noise():
    prior = _fit(_records(630, 12, seed=3))
    own = _fit(_records(135, 1, seed=4, noise=6.0))
    out = combine(own, prior)
    parity = STREAMS.index("parity_front")  # white noise alone: the machine's SD is larger
    assert own.sigma_[parity] > 2 * prior.sigma_[parity]
    assert out.sigma_[parity] == own.sigma_[parity]
    assert out.phi_[parity] == prior.phi_[parity]


def test_a_stream_only_the_machine_watches_keeps_the_machines_own_dynamics():
    short = _records(60, 2, seed=5)  # too short for the lags: the prior does not watch them
    prior = _fit(short)
    own = _fit(_records(630, 1, seed=6))
    lag = STREAMS.index("lag_third")
    assert not prior.watched_[lag] and own.watched_[lag]
    out = combine(own, prior)
    assert out.watched_[lag]
    for name in ("phi_", "sigma_", "long_run_"):
        assert getattr(out, name)[lag] == getattr(own, name)[lag]
