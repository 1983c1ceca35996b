"""The sliver as one more evidence stream of a record's diagnosis.

Where a record has a sliver channel beside it (``generate --sliver``, or a drawframe's
delivery sensor logged on the same clock), :func:`sliver_evidence` watches it as it was
delivered (:class:`drafttwin.sliver.watch.SliverWatch`: running count and CV, a spectrogram
every 50 m over the last 100 m, an alarm when a chimney appears) and diagnoses the whole
channel with the record's own encoders (:func:`drafttwin.sliver.diagnose.with_encoders`). It
sees what the speed residuals cannot: gear run-out, roller eccentricity and other
once-per-revolution defects, which leave chimneys in the sliver.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from drafttwin.data.series import MeasurementSeries
from drafttwin.mechanics import DriveTrain
from drafttwin.sliver import StapleDiagram, read_sliver
from drafttwin.sliver.count import nominal_count_ktex
from drafttwin.sliver.diagnose import SliverDiagnosis, diagnose_sliver, reference_spectrogram
from drafttwin.sliver.encoders import with_encoders
from drafttwin.sliver.record import Sliver, sliver_beside
from drafttwin.sliver.reference import SliverReference
from drafttwin.sliver.watch import SliverWatch

CHUNK = 2000
"""Readings pushed into the watch at a time (as a live twin would receive them)."""


def sliver_evidence(path: str | Path, train: DriveTrain, series: MeasurementSeries,
                    staple: StapleDiagram | None = None, healthy: Sequence[str | Path] = ()
                    ) -> tuple[dict[str, Any], SliverDiagnosis] | None:  # fmt: skip
    """The sliver's evidence for the record at ``path`` (None if it has no sliver channel):
    a JSON-able summary and the whole channel's diagnosis. The first of ``healthy`` with a
    sliver channel is the machine's reference: its own lines are named, not alarmed."""
    beside = sliver_beside(path)
    if beside is None:
        return None
    staple = staple or StapleDiagram.preset("cotton")
    # an emulated record's lumping, as its sidecar says (the twin reads it from the description)
    scale = beside.fibre_scale or 1.0
    sliver = replace(read_sliver(beside.sliver, staple=staple,
                                 option="--data (its sliver channel)"), fibre_scale=scale)  # fmt: skip
    reference = None
    for h in healthy:
        ref = sliver_beside(h)
        if ref is not None:
            reference = replace(read_sliver(ref.sliver, staple=staple,
                                            option="--healthy (its sliver)"),
                                fibre_scale=ref.fibre_scale or 1.0)  # fmt: skip
            break
    sensor_m = beside.sensor_mm * 1e-3
    # the healthy sliver's own lines, learned window by window as the live twin learns them
    lines = None if reference is None else _learned_lines(
        SliverWatch(train, staple, sensor_length_m=sensor_m, learning=True,
                    fibre_scale=reference.fibre_scale), reference)  # fmt: skip
    watch = _push(SliverWatch(train, staple, sensor_length_m=sensor_m, reference=lines,
                              fibre_scale=scale,
                              nominal_ktex=nominal_count_ktex(beside.sidecar)), sliver)  # fmt: skip
    dx = diagnose_sliver(sliver, train, staple, sensor_length_m=sensor_m, reference=reference)  # fmt: skip
    rpm = {r: series.values[:, j] for j, r in enumerate(series.channels)}
    if {"front", "second", "third", "back"} <= rpm.keys():
        dx = with_encoders(dx, sliver, series.time_s, rpm, staple)
    summary = {
        "file": beside.sliver.name,
        "count_ktex": watch.count_ktex,
        "cv_pct": watch.cv_pct,
        "alarms": [a.to_dict() for a in watch.alarms],
        "count_limit": None if watch.count is None else watch.count.status(),
        "count_excursions": [] if watch.count is None else
        [e.to_dict() for e in watch.count.excursions],
        "chimneys": [{"wavelength_m": c.wavelength_m, "amplitude_pct": c.amplitude_pct,
                      "base_pct": c.base_pct, "verdict": c.verdict,
                      "elements": [k.element for k in c.candidates if k.plausible][:4],
                      "encoder_share": c.extra.get("encoder_share")} for c in dx.causes],
        "elements": dx.elements,
        "reference": None if reference is None else reference.info.get("file"),
        "known_lines": [{"wavelength_m": c.wavelength_m, "amplitude_pct": c.amplitude_pct,
                         "verdict": c.verdict} for c in dx.known],
    }  # fmt: skip
    return summary, dx


def _push(watch: SliverWatch, sliver: Sliver) -> SliverWatch:
    """Every reading of ``sliver`` into ``watch``, :data:`CHUNK` at a time."""
    s, x = sliver.delivered_length_m, sliver.linear_density_ktex
    t = sliver.time_s if sliver.time_s is not None else s
    for i in range(0, x.size, CHUNK):
        watch.push(s[i : i + CHUNK], x[i : i + CHUNK], t[i : i + CHUNK])
    return watch


def _learned_lines(watch: SliverWatch, healthy: Sliver) -> SliverReference | None:
    """The lines a learning watch takes from the healthy sliver (None if it is shorter than
    one window: then its whole spectrogram)."""
    _push(watch, healthy).end_learning()
    learned = watch.learned
    return learned if learned is not None else reference_spectrogram(
        healthy, watch.staple, watch.sensor_length_m)  # fmt: skip
