"""Drafting as the rollers turn (sliver.stream, the live plant's sliver) is the offline
simulator continued piece by piece: fed the same surfaces and the same feed it gives the same
sliver, the same sensor readings, the same infeed readings and store clock, to rounding,
whatever the pieces' sizes, and it forgets what it no longer needs."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from drafttwin.sliver import StapleDiagram, SurfaceSpeeds, draft
from drafttwin.sliver.feed import Feed, FeedFault, FeedStream
from drafttwin.sliver.leveller import Autoleveller
from drafttwin.sliver.sensor import SliverSensor
from drafttwin.sliver.stream import StreamDrafting

SEED = 5
V_M_S = np.array([4.29, 0.887, 0.845, 0.65])  # front, second, third, back: a 6.6 draft
FEED = Feed(StapleDiagram.preset("cotton"), faults=(FeedFault(0.5, 0.05),), extra_cv=0.035,
            extra_correlation_m=0.05)  # fmt: skip


@dataclass(frozen=True)
class _Streamed(Feed):
    """The offline simulator fed the streamed feed's realisation (same seed, same grid)."""

    def intensity(self, p0_mm: float, step_mm: float, size: int,
                  rng: np.random.Generator) -> np.ndarray:  # fmt: skip
        stream_rng = np.random.default_rng(np.random.SeedSequence(SEED).spawn(4)[0])
        return FeedStream(self, p0_mm, step_mm, stream_rng).next(size)


def _surfaces(duration_s: float) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(int(duration_s * 2000) + 1) / 2000.0
    return t, t[:, None] * V_M_S[None, :]


def _streamed(t: np.ndarray, length: np.ndarray, leveller: Autoleveller | None,
              scale: float) -> tuple[StreamDrafting, dict[str, np.ndarray]]:  # fmt: skip
    st = StreamDrafting(FEED, seed=SEED, fibre_scale=scale, leveller=leveller)
    rng = np.random.default_rng(1)
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("true", "s", "x", "t", "inf", "fed")}
    i = 0
    while i < t.size:
        n = int(rng.integers(2, 700))  # pieces of any size
        p = st.push(t[i : i + n], length[i : i + n])
        i += n
        for key, a in zip(parts, (p.true_ktex, p.delivered_m, p.ktex, p.time_s, p.infeed_ktex,
                                  p.fed_length_m), strict=True):  # fmt: skip
            parts[key].append(a)
    return st, {k: np.concatenate(v) for k, v in parts.items()}


@pytest.mark.parametrize("leveller", [None, Autoleveller(1.0, 20.0)], ids=["plain", "levelled"])
def test_the_streamed_sliver_is_the_offline_simulators(leveller: Autoleveller | None) -> None:
    t, length = _surfaces(24.0)
    st, got = _streamed(t, length, leveller, scale=16.0)
    given = _Streamed(FEED.staple, FEED.doublings, FEED.count_ktex, FEED.faults, FEED.extra_cv,
                      FEED.extra_correlation_m)  # fmt: skip
    off = draft(SurfaceSpeeds(t, length), given, seed=SEED, fibre_scale=16.0, leveller=leveller)
    n = got["true"].size
    assert n > 0.99 * off.linear_density_ktex.size  # all but the last bins, still open
    np.testing.assert_allclose(got["true"], off.linear_density_ktex[:n], rtol=1e-9)
    sensor = SliverSensor().read(
        off, np.random.default_rng(np.random.SeedSequence(SEED).spawn(4)[3])
    )
    m = got["x"].size
    np.testing.assert_allclose(got["x"], sensor.linear_density_ktex[:m], rtol=1e-9)
    np.testing.assert_allclose(got["s"], sensor.delivered_length_m[:m], atol=1e-12)
    np.testing.assert_allclose(got["t"], sensor.time_s[:m], atol=1e-9)
    if leveller is not None:  # the leveller's readings and the store's clock, as make_sliver's
        lev = off.levelling
        assert st.true_action_point_mm == pytest.approx(lev.true_action_point_mm, abs=1e-9)
        back = np.interp(got["t"], lev.time_s, lev.back_mm)
        infeed = lev.readings.at(back + leveller.sensor.scan_ahead_mm) * FEED.total_ktex
        np.testing.assert_allclose(got["inf"], infeed, rtol=1e-9)
        fed = (back - np.interp(0.0, lev.time_s, lev.back_mm)) * 1e-3
        np.testing.assert_allclose(got["fed"], fed, atol=1e-9)
    # what it keeps is bounded: old rows, fed points and readings were dropped
    assert st._f0 > 0 and st._S.shape[0] < 5000 and st._reads.size < 20_000


def test_the_streamed_feed_does_not_depend_on_the_pieces() -> None:
    def make() -> FeedStream:
        return FeedStream(FEED, -100.0, 0.1, np.random.default_rng(3))

    whole = make().next(30_000)
    pieces = make()
    parts = np.concatenate([pieces.next(n) for n in (1, 999, 4000, 25_000)])
    np.testing.assert_allclose(parts, whole, rtol=1e-12)
    # the fault's line and the extra irregularity are there: a 5 % wave on one of six
    assert 0.5 * 0.035 / np.sqrt(6) < np.std(whole) < 2 * 0.035


def test_a_roller_standing_in_the_first_piece_is_refused() -> None:
    from drafttwin.errors import ConfigError

    t, length = _surfaces(0.1)
    length[:, 3] = 0.0
    with pytest.raises(ConfigError, match="stands"):
        StreamDrafting(FEED).push(t, length)
