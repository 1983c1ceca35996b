"""The live plant makes sliver as it runs (``plant serve --sliver``).

The live stepper's interval-mean speeds give each roller's exact angle at every sample; between
samples the angle runs on at that interval's speed. Each roller's surface length follows on a
2 kHz grid with its healthy radius run-out, ``r theta + e (cos(theta_0 + phase) - cos(theta +
phase))`` as :func:`drafttwin.plant.surface.roller_surface` writes it, and
:class:`drafttwin.sliver.stream.StreamDrafting` drafts the feed through those surfaces a tenth
of a second at a time (through the machine's autoleveller where it has one), read by the
delivery and infeed sensors: the offline plant's sliver channel
(:mod:`drafttwin.plant.sliver_channel`), continued as the machine runs.

Left out against a recorded plant: the speeds' content between samples (the live plant has no
mesh or once-per-revolution torques, plant/live.py), radius run-out faults and damaged flutes.
The leveller's setting is the machine's, fixed while it runs; the twin reads it and never
writes it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, replace
from typing import Any

import numpy as np

from drafttwin._constants import ROLLERS
from drafttwin.plant.live import LivePlant
from drafttwin.plant.sliver_channel import SURFACE_RATE_HZ, SliverSettings
from drafttwin.sliver.leveller import NOMINAL_DRIVE_S, InfeedSensor, true_action_point_mm
from drafttwin.sliver.stream import StreamDrafting
from drafttwin.wire.conventions import PAYLOAD_VERSION
from drafttwin.wire.sliver import SliverBatch

PIECE_S = 0.1
"""Machine time drafted at a time (a batch published), s."""


class LiveSliver:
    """A live machine's sliver channel: call :meth:`after` after each ``step`` or ``skip`` of
    ``plant``; every :data:`PIECE_S` it drafts what the rollers ran and returns the sensors'
    readings as a batch."""

    def __init__(self, plant: LivePlant, settings: SliverSettings, seed: int, name: str) -> None:
        self.plant, self.name, self.settings = plant, name, settings
        train = plant.machine.train
        diam = {str(r.name): float(r.diameter_mm) for r in train.spec.roller}
        self._radius_m = np.array([diam[r] * 5e-4 for r in ROLLERS])
        self._e_m = plant.config.eccentricity.roller_eccentricity_um * 1e-6
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0x511F]))
        self._phase = rng.uniform(0.0, 2 * math.pi, len(ROLLERS))
        self._m = max(1, round(SURFACE_RATE_HZ / plant.rate_hz))
        self._every = max(1, round(PIECE_S * plant.rate_hz))
        leveller = settings.leveller
        self.true_action_point_mm: float | None = None
        self.drafts = self._drafts()  # at the running point: the nominal count's draft
        if leveller is not None:  # the setting in the machine's frame, from its running point
            true = true_action_point_mm(settings.zones.array(), self.drafts,
                                        settings.feed.staple, settings.infeed.scan_ahead_mm)  # fmt: skip
            self.true_action_point_mm = true
            leveller = replace(leveller, action_point_mm=leveller.setting_mm(true),
                               sensor=settings.infeed)  # fmt: skip
        self.leveller = leveller
        self.stream = StreamDrafting(settings.feed, settings.zones, step_mm=settings.step_mm,
                                     seed=seed, fibre_scale=settings.fibre_scale,
                                     leveller=leveller, delivery=settings.delivery,
                                     infeed=settings.infeed)  # fmt: skip
        self._theta0 = 2 * math.pi * plant.revolutions[: len(ROLLERS)]
        self._theta, self._seq = self._theta0.copy(), plant.seq
        self._idx: list[np.ndarray] = [np.array([plant.seq * self._m])]
        self._lengths: list[np.ndarray] = [np.zeros((1, len(ROLLERS)))]
        self._since = 0
        self.batches = 0
        self.readings = 0

    def _drafts(self) -> dict[str, float]:
        """The zones' and the total draft at the running point (one look-ahead step,
        undone)."""
        p = self.plant
        snap = p.stepper.snapshot()
        try:
            rpm = p.stepper.step(p.supply_hz)
        finally:
            p.stepper.restore(snap)
        v = np.abs(rpm[p._rollers]) * self._radius_m  # surface speed up to a constant
        return {
            "break": float(v[2] / v[3]),
            "middle": float(v[1] / v[2]),
            "main": float(v[0] / v[1]),
            "total": float(v[0] / v[3]),
        }

    def describe(self) -> dict[str, Any]:
        """What the machine says of its sliver (the wire's description, a sidecar's section
        without the truth: no feed faults, no true action point, the drive's nominal lag)."""
        s, lev = self.settings, self.leveller
        infeed = asdict(InfeedSensor(s.infeed.averaging_mm, s.infeed.noise, s.infeed.pitch_mm,
                                     s.infeed.scan_ahead_mm))  # fmt: skip
        return {"v": PAYLOAD_VERSION, "staple": s.feed.staple.describe(),
                "doublings": s.feed.doublings, "feed_ktex": s.feed.count_ktex,
                "drafts": self.drafts,
                "delivery_sensor": asdict(s.delivery), "infeed_sensor": infeed,
                "step_mm": s.step_mm, "fibre_scale": s.fibre_scale,
                "leveller": None if lev is None else {
                    "intensity": lev.intensity, "action_point_mm": lev.action_point_mm,
                    "reference": "the feed's nominal count",
                    "drive": {"time_constant_s": NOMINAL_DRIVE_S}}}  # fmt: skip

    def after(self) -> SliverBatch | None:
        """The rollers' travel since the last call; a batch of readings once a piece is due
        (None otherwise, or when the piece completed no reading yet)."""
        p = self.plant
        n = p.seq - self._seq
        if n <= 0:
            return None
        theta = 2 * math.pi * p.revolutions[: len(ROLLERS)]
        fine = n * self._m
        frac = np.arange(1, fine + 1)[:, None] / fine
        th = self._theta + frac * (theta - self._theta)
        length = self._radius_m * (th - self._theta0) + self._e_m * (
            np.cos(self._theta0 + self._phase) - np.cos(th + self._phase))  # fmt: skip
        self._idx.append(self._seq * self._m + np.arange(1, fine + 1))
        self._lengths.append(length)
        self._theta, self._seq = theta, p.seq
        self._since += n
        if self._since < self._every:
            return None
        idx, lengths = np.concatenate(self._idx), np.vstack(self._lengths)
        self._idx, self._lengths, self._since = [], [], 0
        piece = self.stream.push(p.t0_s + idx / (p.rate_hz * self._m), lengths)
        if piece.delivered_m.size == 0:
            return None
        self.batches += 1
        self.readings += piece.delivered_m.size
        return SliverBatch(self.name, self.batches, piece.time_s, piece.delivered_m, piece.ktex,
                           piece.infeed_ktex, piece.fed_length_m).published()  # fmt: skip

    def summary(self) -> str:
        """One line for the end of a run: the true sliver's length, count and CV."""
        count, cv = self.stream.true_evenness()
        return (
            f"{self.name}: {self.stream.delivered_m:.1f} m of sliver, count {count:.4f} "
            f"ktex, CV {cv:.3f} % (true), {self.readings} readings in {self.batches} batches"
        )


__all__ = ["PIECE_S", "LiveSliver"]
