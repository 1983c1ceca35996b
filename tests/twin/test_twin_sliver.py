"""The live twin takes the sliver channel as one more evidence stream: running count and CV,
a spectrogram every 50 m over the last 100 m, an alarm when a chimney appears, named with
its element (replayed from a plant record with a sliver channel)."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from drafttwin.plant import Plant
from drafttwin.plant.faults import FaultSpec
from drafttwin.plant.sliver_channel import SliverSettings
from drafttwin.twin.build import build_service

pytestmark = pytest.mark.slow


def test_a_replayed_sliver_channel_raises_a_named_chimney_alarm(twin_files, tmp_path: Path):
    _, model = twin_files
    rec = Plant().run(30.0, 100.0, seed=4, sliver=SliverSettings(),
                      faults=[FaultSpec.parse("front:eccentricity:severity=0.3:onset=0")])  # fmt: skip
    record = tmp_path / "ecc.parquet"
    rec.write(record)
    service = build_service(model, [f"replay:{record}?speed=inf"], detector="none")
    asyncio.run(service.run())
    (st,) = service.states.values()
    assert st.sliver is not None
    summary = st.sliver.summary()
    assert summary["count_ktex"] == pytest.approx(rec.sliver.summary["true_count_ktex"], rel=0.01)
    assert summary["delivered_m"] > 120
    events = [e for e in st.alarms if e.kind == "sliver-chimney"]
    assert len(events) == 1, [e.detail for e in st.alarms]
    assert "14.14 cm" in events[0].detail and "roller front" in events[0].detail
    assert service.status()["machines"][st.twin.name]["sliver"]["alarms"] == 1


def test_a_record_without_sliver_keeps_the_twin_as_it_was(twin_files):
    record, model = twin_files
    service = build_service(model, [f"replay:{record}?speed=inf"], detector="none")
    asyncio.run(service.run())
    (st,) = service.states.values()
    assert st.sliver is None
    assert not [e for e in st.alarms if e.kind == "sliver-chimney"]
