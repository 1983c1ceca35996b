"""The served plant's physics computed ahead of the wall clock (a worker thread, chunks): the
samples are those of stepping one by one, bit for bit, faults included, whatever the
look-ahead; the worker stops at the plant's duration and when the plant stops."""

from __future__ import annotations

import asyncio
import time

import numpy as np
import pytest

from drafttwin.plant.faults import FaultSpec
from drafttwin.plant.live import LivePlant, LiveSample
from drafttwin.plant.serve.channels import as_published, plant_channels
from drafttwin.plant.serve.feed import Feed
from drafttwin.plant.serve.opcua import serve_opcua
from drafttwin.plant.serve.pacing import Pacing

from ._twin import free_port

pytestmark = pytest.mark.timeout(120)

FAULTS = ("main_belt:belt_wear:severity=0.5:onset=0.5",  # machine fault: the kernel's tables
          "third:gain:severity=0.01:onset=0.3",  # sensor faults: what the encoders say
          "front:stuck:severity=0.2:onset=0.8")  # fmt: skip


def _row(s: LiveSample) -> np.ndarray:
    return np.array([s.seq, s.time_s, *s.rollers_rpm, s.motor_rpm, s.supply_hz, *s.true_rpm])


def _plant(physics: str = "full", faults: tuple[str, ...] = (), seed: int = 5) -> LivePlant:
    p = LivePlant(seed, 100.0, physics=physics, faults=[FaultSpec.parse(f) for f in faults])
    p.set_supply(35.0)  # the VFD ramps through the whole record
    return p


def _stepped(p: LivePlant, n: int) -> np.ndarray:
    return np.array([_row(p.step()) for _ in range(n)])


@pytest.mark.parametrize(("physics", "faults"), [("full", FAULTS), ("reduced", ())])
def test_samples_computed_ahead_are_those_stepped_one_by_one(physics: str,
                                                             faults: tuple[str, ...]) -> None:  # fmt: skip
    """Computed 1, 7 or 40 samples ahead (and irregularly): the same floats, NaNs (dropped
    samples) at the same places, the faults from the same sample on."""
    n = 120
    one_by_one = _stepped(_plant(physics, faults), n)
    for ahead in (1, 7, 40, None):
        p, rows = _plant(physics, faults), []
        chunks = iter([3, 1, 11, 2, 30, 5, 9] * 10)
        while len(rows) < n:
            if p.ahead == 0:
                p.compute(ahead if ahead is not None else next(chunks))
            rows.append(_row(p.step()))
        assert np.array_equal(np.array(rows), one_by_one, equal_nan=True), ahead
    if faults:  # the belt's creep and the gain are there, from their onsets
        healthy = _stepped(_plant(physics), n)
        assert np.array_equal(healthy[:50, 8:], one_by_one[:50, 8:])  # true speeds before onset
        assert not np.array_equal(healthy[60:, 8:], one_by_one[60:, 8:])


def test_the_worker_computes_ahead_and_stops_at_the_end() -> None:
    """Two plants fed by the worker (0.1 s ahead) while a loop takes samples at irregular
    times: the samples of stepping one by one; the worker keeps ahead, never past ``end``, and
    ends when the feed closes."""
    n = 60
    expected = [_stepped(_plant("reduced", seed=s), n) for s in (1, 2)]
    plants = [_plant("reduced", seed=s) for s in (1, 2)]
    ahead_seen = 0
    with Feed(plants, 100.0, ahead_s=0.1, chunk_s=0.03) as feed:
        feed.end = n
        assert all(p.ahead == 10 for p in plants)  # filled before the clock starts
        rows: list[list[np.ndarray]] = [[], []]
        for k in range(n):
            time.sleep(0.002 if k % 7 else 0.02)
            ahead_seen = max(ahead_seen, plants[0].ahead)
            for p, out in zip(plants, rows, strict=True):
                out.append(_row(p.step()))
            feed.took()
        thread = feed._thread
        assert thread is not None and thread.is_alive()
    assert not thread.is_alive()
    assert ahead_seen >= 5 and all(p.computed == n for p in plants)
    for got, want in zip(rows, expected, strict=True):
        assert np.array_equal(np.array(got), want, equal_nan=True)


def test_a_served_plant_publishes_the_samples_of_stepping_one_by_one() -> None:
    """``serve_opcua`` for 1 s of full physics (computed ahead in its worker): what it
    publishes is, bit for bit, a plant of the same seed stepped one by one; its lateness is
    counted as before."""
    got: list[LiveSample] = []
    pacing = Pacing(100.0)
    asyncio.run(serve_opcua(f"opc.tcp://127.0.0.1:{free_port()}", ["m1"], seed=4,
                            duration_s=1.0, pacing=pacing,
                            on_sample=lambda _name, s: got.append(s)))  # fmt: skip
    plain = LivePlant(4, 100.0)
    plain.t0_s = pacing.t0_s
    channels = plant_channels(plain)
    want = [_row(as_published(plain.step(), channels)) for _ in range(100)]
    assert len(got) == 100
    assert np.array_equal(np.array([_row(s) for s in got]), np.array(want), equal_nan=True)
    assert pacing.tick == 100 and 0 <= pacing.late_ticks <= 100 and pacing.max_seen_lag_s >= 0


def test_a_skip_drops_the_samples_computed_ahead_then_integrates_the_rest() -> None:
    """Behind the wall clock with 10 samples computed ahead: skipping 5 drops 5 of them (the
    next sample's physics is exactly that of stepping through), skipping 49 drops the 10 and
    integrates the other 39 in one call (close to stepping through); the counter jumps."""
    stepped = _plant("reduced")
    for _ in range(5):
        stepped.step()
    sa = stepped.step()
    for _ in range(49 - 6):
        stepped.step()
    sb = stepped.step()
    p = _plant("reduced")
    p.compute(10)
    p.skip(5)
    s5 = p.step()
    assert s5.seq == sa.seq == 6 and np.array_equal(s5.true_rpm, sa.true_rpm)
    q = _plant("reduced")
    q.compute(10)
    q.skip(49)
    s49 = q.step()
    assert s49.seq == sb.seq == 50 and q.computed == 50
    np.testing.assert_allclose(s49.true_rpm, sb.true_rpm, rtol=2e-3)
