"""The live twin learns a machine's own sliver lines while it learns its healthy state,
keeps them in its baseline, and alarms only on new chimneys after (as ``diagnose
--healthy`` does offline). A healthy machine whose leveller was set right raised a
"sliver chimney ... roller third" alarm live on its middle rollers' 10-um run-out."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import numpy as np
import pytest

from drafttwin.diagnosis.detect import FaultDetector
from drafttwin.diagnosis.residuals import block_features
from drafttwin.errors import DataError
from drafttwin.sliver.reference import SliverReference
from drafttwin.twin.build import build_service
from drafttwin.twin.store.baselines import Baseline, BaselineStore

from ._twin import run_cli
from .test_twin_faults import samples

SHA = "0" * 64


def _reference() -> SliverReference:
    return SliverReference(np.array([0.5, 0.59, 0.64]), np.array([0.1, 0.21, 0.1]), 9, 500.0)


def test_the_baseline_keeps_the_machines_lines_and_refuses_them_damaged(tmp_path: Path) -> None:
    healthy = [block_features(y, yh, t, 1.0) for t, y, yh in (samples(s, 120) for s in range(3))]
    detector = FaultDetector(reference_s=10.0).fit(healthy)
    store = BaselineStore(tmp_path)
    path = store.save(Baseline("m1", detector, SHA, None, 120.0, 0.0, 130.0,
                               sliver_reference=_reference()))  # fmt: skip
    back = store.load("m1")
    assert back is not None and back.sliver_reference is not None
    np.testing.assert_array_equal(back.sliver_reference.amplitude_pct, [0.1, 0.21, 0.1])
    assert (back.sliver_reference.windows, back.sliver_reference.metres) == (9, 500.0)
    doc = json.loads(path.read_text())
    doc.pop("sliver_reference")  # a baseline stored before the lines were kept
    path.write_text(json.dumps(doc))
    old = store.load("m1")
    assert old is not None and old.sliver_reference is None
    doc["sliver_reference"] = {"wavelength_m": [0.5], "amplitude_pct": [-1.0], "windows": 1,
                               "metres": 100.0}  # fmt: skip
    path.write_text(json.dumps(doc))
    with pytest.raises(DataError, match="amplitude_pct") as err:
        store.load("m1")
    assert str(path) in str(err.value) and "learns again" in str(err.value)


@pytest.mark.long
def test_a_healthy_levelled_machine_learns_its_lines_and_raises_no_chimney(
    twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    """Machine 7, leveller at its true action point (75 s, about 320 m): without its lines the
    twin alarms on the 59-60-cm roller line; learning 45 s (two windows) takes them, no alarm,
    stores them, and a twin restarted on that store judges the same record by them (no alarm)."""
    _, model = twin_files
    record = tmp_path / "h.parquet"
    made = run_cli("generate", "--duration", "75", "--seed", "3", "--machine-seed", "7",
                   "--sliver", "--leveller", "1,0", "--out", str(record), timeout=300)  # fmt: skip
    assert made.returncode == 0, made.stderr

    def replay(**kw: object) -> list[str]:
        service = build_service(model, [f"replay:{record}?speed=inf&machine=m7"], **kw)  # type: ignore[arg-type]
        asyncio.run(service.run())
        st = service.states["m7"]
        return [e.detail for e in st.alarms if e.kind == "sliver-chimney"]

    bare = replay(detector="none")
    assert any("roller second" in d or "roller third" in d for d in bare), bare
    store = tmp_path / "store"
    assert replay(detector="auto", learn_s=45.0, store_dir=store) == []
    kept = BaselineStore(store / "baselines").load("m7")
    assert kept is not None and kept.sliver_reference is not None
    assert kept.sliver_reference.windows >= 2
    assert replay(detector="auto", store_dir=store) == []  # restored: watched at once


def test_the_page_draws_the_machines_own_lines_apart_from_new_chimneys() -> None:
    """The card said "no chimney" beside a red chimney dot at the machine's own 60-cm line."""
    from types import SimpleNamespace

    from drafttwin.twin.sliverdesk import _own_channels

    centres = 0.01 * 2.0 ** (np.arange(55, 64) / 10)
    known = [SimpleNamespace(wavelength_m=0.6027, extra={"channel_m": float(centres[4])})]
    assert _own_channels(centres, known) == [k == 4 for k in range(9)]
    assert _own_channels(centres, []) == [False] * 9
