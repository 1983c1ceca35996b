"""The plant makes sliver: the delivered sliver drafted by the true roller surfaces, and the
readings of the drawframe's delivery and infeed sensors.

The plant's rollers turn as its simulation says, at 2 kHz (:mod:`drafttwin.plant.surface`:
radius run-out included); the drafting simulator (:mod:`drafttwin.sliver`) draws the fed
slivers' fibres and drafts them through those surfaces. The delivery sensor reads the true
sliver; the infeed scanning rollers read the fed slivers before the back roller.

Default feed (assumptions, docs/sliver.md): six cotton card slivers of 5.5 ktex each, with
an extra irregularity of 3.5 % per card sliver above the random sliver (correlation length
5 cm on the card sliver): trade figures put card sliver at a CV of 3-4.5 %, far above its
Martindale limit (about 0.24 % for 34 000 fibres), but no published nomogram was found.
"""

from __future__ import annotations

import contextlib
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from drafttwin._io import atomic_path
from drafttwin.sliver import DraftingZones, Feed, FeedFault, Sliver, StapleDiagram, SurfaceSpeeds
from drafttwin.sliver import draft as draft_sliver
from drafttwin.sliver.irregularity import evenness
from drafttwin.sliver.leveller import Autoleveller, InfeedSensor
from drafttwin.sliver.record import frame_to_file
from drafttwin.sliver.sensor import SliverSensor

SURFACE_RATE_HZ = 2000.0
"""Rate of the true roller surfaces that draft the plant's sliver (2 mm of sliver)."""


def sliver_paths(path: Path) -> tuple[Path, Path]:
    """The sliver files beside a plant record: ``<stem>.sliver<suffix>`` (sensors) and
    ``<stem>.sliver.truth<suffix>`` (the true sliver)."""
    return (path.with_name(f"{path.stem}.sliver{path.suffix}"),
            path.with_name(f"{path.stem}.sliver.truth{path.suffix}"))  # fmt: skip


def default_feed(faults: tuple[FeedFault, ...] = ()) -> Feed:
    return Feed(StapleDiagram.preset("cotton"), doublings=6, count_ktex=5.5, faults=faults,
                extra_cv=0.035, extra_correlation_m=0.05)  # fmt: skip


@dataclass(frozen=True)
class SliverSettings:
    """What the plant drafts, how it measures it, and its autoleveller (None: none).

    The infeed scanning rollers (``infeed``: 20 mm contact, 0.3 % noise, a reading per mm of
    fed sliver, 600 mm before the back nip; assumptions) are the leveller's sensor where
    there is one: its readings are the ones written."""

    feed: Feed = field(default_factory=default_feed)
    zones: DraftingZones = field(default_factory=DraftingZones)
    delivery: SliverSensor = field(default_factory=SliverSensor)
    infeed: InfeedSensor = field(default_factory=InfeedSensor)
    fibre_scale: float = 1.0
    step_mm: float = 1.0
    leveller: Autoleveller | None = None

    def record(self) -> dict[str, Any]:
        feed = self.feed
        return {"staple": feed.staple.describe(), "doublings": feed.doublings,
                "feed_ktex": feed.count_ktex, "feed_extra_cv": feed.extra_cv,
                "feed_extra_correlation_m": feed.extra_correlation_m,
                "feed_faults": [asdict(f) for f in feed.faults],
                "feed_events": feed.events(),
                "gauges_mm": asdict(self.zones), "delivery_sensor": asdict(self.delivery),
                "infeed_sensor": asdict(self.infeed), "fibre_scale": self.fibre_scale,
                "step_mm": self.step_mm, "scan_ahead_mm": self.infeed.scan_ahead_mm}  # fmt: skip


@dataclass(frozen=True)
class SliverChannel:
    """The plant's sliver: the true sliver and the sensors' readings.

    Attributes:
        true: the delivered sliver on its fine grid (ktex).
        delivery: the delivery sensor's readings (ktex) on its pitch.
        infeed_ktex: the infeed sensor's readings of all fed slivers (ktex) at the delivery
            readings' times (the reading the scanning rollers hold then).
        fed_length_m: the feeding (back) roller's travel at those times, m from the record's
            start: the length clock of a levelling drawframe's store.
        summary: count, CV and the drafting's provenance (JSON-able).
    """

    true: Sliver
    delivery: Sliver
    infeed_ktex: np.ndarray
    fed_length_m: np.ndarray
    summary: dict[str, Any]

    def frames(self) -> tuple[pd.DataFrame, pd.DataFrame]:
        measured = self.delivery.to_frame()
        measured["infeed_ktex"] = self.infeed_ktex
        measured["fed_length_m"] = self.fed_length_m
        return measured, self.true.to_frame()

    def write(self, path: Path, truth: Path, stack: contextlib.ExitStack) -> None:
        """Write both frames to temporary files in ``stack`` (renamed when it closes)."""
        measured, true = self.frames()
        for frame, target in ((measured, path), (true, truth)):
            frame_to_file(frame, stack.enter_context(atomic_path(target)), target.suffix)


def make_sliver(time_s: np.ndarray, length_m: np.ndarray, settings: SliverSettings,
                rng: np.random.Generator, seed: int) -> SliverChannel:  # fmt: skip
    """Draft the plant's sliver from its true roller surfaces (``length_m`` ``(n, 4)`` on
    ``time_s``), through its autoleveller where it has one, and read it with the sensors."""
    speeds = SurfaceSpeeds.from_lengths(time_s, length_m, "plant: true roller surfaces")
    leveller = settings.leveller
    if leveller is not None:
        leveller = replace(leveller, sensor=settings.infeed)
    true = draft_sliver(speeds, settings.feed, settings.zones, step_mm=settings.step_mm,
                        seed=seed, fibre_scale=settings.fibre_scale, leveller=leveller)  # fmt: skip
    delivery = settings.delivery.read(true, rng)
    assert true.fed is not None and delivery.time_s is not None
    if true.levelling is not None:
        lev = true.levelling
        back_mm = np.interp(delivery.time_s, lev.time_s, lev.back_mm)
        readings = lev.readings
    else:
        back_mm = np.interp(delivery.time_s, time_s, (length_m[:, 3] - length_m[0, 3]) * 1e3)
        start, step, relative = true.fed
        fed_speed = (length_m[-1, 3] - length_m[0, 3]) * 1e3 / (time_s[-1] - time_s[0])
        readings = settings.infeed.readings(relative, start, step, settings.feed.staple, rng,
                                            float(fed_speed))  # fmt: skip
    infeed = readings.at(back_mm + settings.infeed.scan_ahead_mm) * settings.feed.total_ktex
    back_mm = back_mm - (
        np.interp(0.0, true.levelling.time_s, true.levelling.back_mm)
        if true.levelling is not None
        else 0.0
    )  # 0 at the record's start
    ev = evenness(true.linear_density_ktex, true.step_m, settings.feed.staple,
                  settings.fibre_scale)  # fmt: skip
    summary = {**settings.record(), "fibres": true.info.get("fibres"),
               "delivered_m": true.length_m, "true_count_ktex": ev.count_ktex,
               "true_cv_pct": ev.cv_pct, "martindale_cv_pct": ev.martindale_cv_pct,
               "drafts": speeds.drafts(), "leveller": true.info.get("leveller")}  # fmt: skip
    return SliverChannel(true, delivery, infeed, back_mm * 1e-3, summary)
