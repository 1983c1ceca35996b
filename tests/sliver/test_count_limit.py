"""The count's limit: a card sliver running out with no leveller to make up for it took the
delivered count 16.7 % down and neither the live twin nor `diagnose` said a word (the
nineteenth session's left item; research/sliver.md 5: quality monitors stop the machine when
the count passes its limit)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from drafttwin.cli import app
from drafttwin.sliver.count import BACK, LENGTH_M, LIMIT_PCT, CountWatch, nominal_count_ktex

STEP_M = 0.001


def _sliver(gap: tuple[float, float], length_m: float = 40.0) -> tuple[np.ndarray, np.ndarray]:
    """5 ktex with one sliver of six missing over ``gap`` (delivered m)."""
    s = np.arange(1, int(length_m / STEP_M) + 1) * STEP_M
    x = np.where((s > gap[0]) & (s <= gap[1]), 5.0 * 5 / 6, 5.0)
    return s, x


def test_the_count_leaves_and_comes_back_where_the_closed_form_says() -> None:
    """A 1/6 step: the 5-m mean passes -5 % when 5/16.7 of the window lies in the gap (1.5 m
    into it) and comes back within 4.5 % when 4.5/16.7 still does (3.65 m past its end)."""
    s, x = _sliver((10.0, 25.0))
    watch = CountWatch(5.0)
    got = watch.push(s, x, s / 4.0)
    assert [e.out for e in got] == [True, False]
    drop = 100 / 6
    assert got[0].delivered_m == pytest.approx(10.0 + LENGTH_M * LIMIT_PCT / drop, abs=2 * STEP_M)
    back = 25.0 + LENGTH_M * (1 - BACK * LIMIT_PCT / drop)
    assert got[1].delivered_m == pytest.approx(back, abs=2 * STEP_M)
    assert got[0].deviation_pct == pytest.approx(-LIMIT_PCT, abs=0.01)
    assert "-5.0 % off the nominal 5.000 ktex" in got[0].text()
    assert watch.outside is False and len(watch.excursions) == 2


def test_readings_in_batches_give_what_the_whole_record_gives() -> None:
    s, x = _sliver((10.0, 25.0))
    x = x * (1 + 0.01 * np.random.default_rng(1).standard_normal(x.size))  # no exact ties
    whole = CountWatch(5.0).push(s, x, s)
    watch = CountWatch(5.0)
    rng = np.random.default_rng(3)
    cuts = np.sort(rng.choice(np.arange(1, s.size), 60, replace=False))
    parts = [watch.push(a, b, a) for a, b in zip(np.split(s, cuts), np.split(x, cuts),
                                                  strict=True)]  # fmt: skip
    got = [e for p in parts for e in p]
    assert [(e.out, e.delivered_m, e.time_s) for e in got] == [
        (e.out, e.delivered_m, e.time_s) for e in whole
    ]
    assert [e.count_ktex for e in got] == pytest.approx([e.count_ktex for e in whole], rel=1e-12)


def test_a_count_within_the_limit_and_the_first_metres_say_nothing() -> None:
    """A 2-m wave of 3 % (the leveller benchmark's feed faults reach 5 %, and a 5-m mean
    averages them) stays within; the first 5 m are not judged (no whole length yet)."""
    s = np.arange(1, 40_001) * STEP_M
    x = 5.0 * (1 + 0.03 * np.sin(2 * np.pi * s / 2.0))
    assert CountWatch(5.0).push(s, x, s) == []
    # 20 % off over the first 0.5 m: alone before a whole length lies behind, 2 % after
    x0 = np.where(s < 0.5, 4.0, 5.0)
    assert CountWatch(5.0).push(s, x0, s) == []


def test_the_nominal_comes_from_the_description_and_is_checked() -> None:
    section = {"feed_ktex": 5.5, "doublings": 6, "drafts": {"total": 6.57}}
    assert nominal_count_ktex(section) == pytest.approx(33 / 6.57)
    for bad in ({}, {**section, "feed_ktex": "x"}, {**section, "drafts": {"total": 0}},
                {**section, "feed_ktex": -1.0}, {**section, "drafts": None},
                {**section, "feed_ktex": float("nan")}):  # fmt: skip
        assert nominal_count_ktex(bad) is None


@pytest.mark.slow
def test_the_record_diagnosis_says_when_a_missing_sliver_takes_the_count_off(
    tmp_path: Path,
) -> None:
    """`generate --sliver --feed-fault missing=...` without a leveller: the sliver's evidence
    of `diagnose` (the same watch as the live twin's) lists the count leaving its limit and
    coming back, against the sidecar's nominal count."""
    from drafttwin.data.io import read_measurements
    from drafttwin.diagnosis.sliver_evidence import sliver_evidence
    from drafttwin.mechanics import DriveTrain

    out = tmp_path / "rec.csv"
    result = CliRunner().invoke(app, ["generate", "--duration", "14", "--seed", "2",
                                      "--machine-seed", "11", "--sliver", "--fibre-scale", "8",
                                      "--feed-fault", "missing=2-4", "--quiet", "--out",
                                      str(out)])  # fmt: skip
    assert result.exit_code == 0, result.output
    section = json.loads(out.with_suffix(".json").read_text())["sliver"]
    nominal = nominal_count_ktex(section)
    assert nominal is not None
    got = sliver_evidence(out, DriveTrain.preset("fa320a"), read_measurements(out))
    assert got is not None
    ev = got[0]
    assert ev["count_limit"]["nominal_ktex"] == pytest.approx(nominal)
    assert [e["out"] for e in ev["count_excursions"]] == [True, False], ev["count_excursions"]
    low = ev["count_excursions"][0]
    assert low["deviation_pct"] < -LIMIT_PCT and low["delivered_m"] > 2 * section["drafts"]["total"]
    # `sliver diagnose` holds the record's count to the same limit with the same watch
    result = CliRunner().invoke(app, ["sliver", "diagnose", "--data", str(out), "--json"])
    assert result.exit_code == 0, result.output
    doc = json.loads(result.output)
    assert [(e["out"], e["delivered_m"]) for e in doc["count_excursions"]] == [
        (e["out"], e["delivered_m"]) for e in ev["count_excursions"]
    ]
    text = CliRunner().invoke(app, ["sliver", "diagnose", "--data", str(out)]).output
    assert "off the nominal" in text and "back within" in text
    # a tester's export names no nominal: said, and --nominal-count gives one
    sliver = out.with_name("rec.sliver.csv")
    export = tmp_path / "tester.csv"
    rows = sliver.read_text().splitlines()
    head = rows[0].split(",")
    cols = [head.index("delivered_length_m"), head.index("linear_density_ktex")]
    export.write_text("length_m,linear_density_ktex\n" + "\n".join(
        ",".join(r.split(",")[c] for c in cols) for r in rows[1:]) + "\n")  # fmt: skip
    text = CliRunner().invoke(app, ["sliver", "diagnose", "--data", str(export)]).output
    assert "count limit not checked" in text and "--nominal-count" in text
    result = CliRunner().invoke(app, ["sliver", "diagnose", "--data", str(export),
                                      "--nominal-count", f"{nominal:.4f}", "--json"])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert [e["out"] for e in json.loads(result.output)["count_excursions"]] == [True, False]
    refused = CliRunner().invoke(app, ["sliver", "diagnose", "--spectrogram", str(export),
                                       "--nominal-count", "5"])  # fmt: skip
    assert refused.exit_code == 2 and "--nominal-count" in refused.output
