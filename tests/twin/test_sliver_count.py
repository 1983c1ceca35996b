"""The live twin watches the delivered count against the machine's nominal, as `diagnose`
does offline (one watch): a card sliver running out with no leveller took the count 16.7 %
down and the twin said nothing."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from drafttwin.data.io import read_measurements
from drafttwin.diagnosis.sliver_evidence import sliver_evidence
from drafttwin.mechanics import DriveTrain
from drafttwin.twin.build import build_service

from ._twin import run_cli

pytestmark = pytest.mark.slow


def test_a_missing_sliver_alarms_live_as_offline(twin_files: tuple[Path, Path],
                                                 tmp_path: Path) -> None:  # fmt: skip
    _, model = twin_files
    record = tmp_path / "miss.parquet"
    made = run_cli("generate", "--duration", "14", "--seed", "2", "--machine-seed", "11",
                   "--sliver", "--fibre-scale", "8", "--feed-fault", "missing=2-4", "--out",
                   str(record), timeout=300)  # fmt: skip
    assert made.returncode == 0, made.stderr
    service = build_service(model, [f"replay:{record}?speed=inf&machine=m11"], detector="none")
    asyncio.run(service.run())
    st = service.states["m11"]
    live = [(e.kind, e.detail) for e in [*st.alarms, *st.events]
            if e.kind in ("sliver-count", "sliver-count-back")]  # fmt: skip
    offline = sliver_evidence(record, DriveTrain.preset("fa320a"), read_measurements(record))
    assert offline is not None
    assert [k for k, _ in live] == ["sliver-count", "sliver-count-back"], live
    texts = [e["deviation_pct"] for e in offline[0]["count_excursions"]]
    assert len(texts) == 2
    for (_, detail), dev in zip(live, texts, strict=True):
        assert f"{dev:+.1f} %" in detail
    assert "off the nominal" in live[0][1] and "card sliver run out" in live[0][1]
    status = service.states["m11"].sliver
    assert status is not None and status.summary()["count_limit"]["excursions"] == 2
    # the retained sliver state a late MQTT client reads carries the limit, as its schema says
    import jsonschema

    from drafttwin.twin.publish.payload import schema, sliver

    doc = sliver(st)
    assert doc is not None
    jsonschema.Draft202012Validator(schema("sliver")).validate(doc)
    assert doc["sliver"]["count_limit"]["outside"] is False
    assert doc["sliver"]["count_limit"]["excursions"] == 2
