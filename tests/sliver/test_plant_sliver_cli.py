"""The plant makes sliver, and the sliver commands read it (issue 26's done-when, fixed seeds).

Full fibre counts (1e8 fibres per record), so each record takes seconds: module fixtures.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

from drafttwin.cli import app
from drafttwin.sliver import Feed, StapleDiagram

runner = CliRunner()
pytestmark = pytest.mark.slow


def _run(*args: str) -> str:
    result = runner.invoke(app, list(args))
    assert result.exit_code == 0, result.output
    return result.output


def _refused(*args: str) -> str:
    result = runner.invoke(app, list(args))
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    return result.output


@pytest.fixture(scope="module")
def records(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("sliver")
    runs = {"healthy": ("6", None), "eccentric": ("4", "front:eccentricity:severity=0.3:onset=0"),
            "gear": ("5", "A-B:runout:severity=80:onset=0")}  # fmt: skip
    out = {}
    for name, (seed, fault) in runs.items():
        args = ["generate", "--duration", "25", "--seed", seed, "--sliver", "--quiet",
                "--out", str(d / f"{name}.csv")]  # fmt: skip
        if fault:
            args += ["--fault", fault]
        _run(*args)
        out[name] = d / f"{name}.csv"
    return out


def _diagnose(path: Path) -> dict:
    return json.loads(_run("sliver", "diagnose", "--data", str(path), "--json"))


def test_generate_writes_the_sliver_channel_beside_the_record(records):
    path = records["healthy"]
    sliver = pd.read_csv(path.with_name("healthy.sliver.csv"))
    truth = pd.read_csv(path.with_name("healthy.sliver.truth.csv"))
    assert list(sliver.columns) == ["delivered_length_m", "time", "linear_density_ktex",
                                    "infeed_ktex", "fed_length_m"]  # fmt: skip
    assert truth["delivered_length_m"].diff().iloc[1:].round(9).eq(0.001).all()
    info = json.loads(path.with_suffix(".json").read_text())
    assert info["files"]["sliver"] == "healthy.sliver.csv"
    # count = fed count x doublings / draft (the true sliver, drafted by the true rollers)
    drafts = info["sliver"]["drafts"]
    assert truth["linear_density_ktex"].mean() == pytest.approx(33.0 / drafts["total"], rel=3e-3)
    # the infeed sensor reads the six card slivers together
    assert sliver["infeed_ktex"].mean() == pytest.approx(33.0, rel=0.01)
    # the store's length clock: the feeding roller's travel, the delivered length over the
    # draft without a leveller
    fed = sliver["fed_length_m"].to_numpy()
    assert fed[0] == pytest.approx(0.0, abs=1e-3) and (fed[1:] >= fed[:-1]).all()
    slope = (fed[-1] - fed[0]) / (
        sliver["delivered_length_m"].iloc[-1] - sliver["delivered_length_m"].iloc[0]
    )
    assert slope == pytest.approx(1 / drafts["total"], rel=2e-3)


def test_a_healthy_record_has_no_chimney_and_the_cv_its_settings_imply(records):
    dx = _diagnose(records["healthy"])
    assert dx["chimneys"] == []
    info = json.loads(records["healthy"].with_suffix(".json").read_text())
    feed = Feed(StapleDiagram.preset("cotton"), 6, 5.5, extra_cv=0.035, extra_correlation_m=0.05)
    implied = feed.expected_cv_pct(info["sliver"]["drafts"]["total"])
    assert dx["evenness"]["cv_pct"] == pytest.approx(implied, rel=0.10)


def test_an_eccentric_front_roller_leaves_its_chimney_and_is_named_first(records):
    dx = _diagnose(records["eccentric"])
    circumference = math.pi * 0.045
    near = [
        c for c in dx["chimneys"] if abs(math.log2(c["wavelength_m"] / circumference)) <= 0.1
    ]  # within one channel
    assert near, dx["chimneys"]
    assert near[0]["candidates"][0]["element"] == "roller front"
    assert dx["elements"][0] == "roller front"


def test_a_gear_run_out_is_named_with_the_encoders(records):
    dx = _diagnose(records["gear"])
    first = dx["chimneys"][0]
    assert abs(math.log2(first["wavelength_m"] / (math.pi * 0.045))) <= 0.1
    names = [c["element"] for c in first["candidates"]]
    assert names[0] == "gear B (A-B)"
    assert first["extra"]["encoder_share"] > 0.6  # the encoders see this one


def test_sliver_simulate_from_the_plants_true_speeds_and_a_tester_table(records, tmp_path):
    out = tmp_path / "s.csv"
    said = _run("sliver", "simulate", "--speeds", str(records["eccentric"]), "--truth",
                "--fibre-scale", "4", "--out", str(out), "--quiet")  # fmt: skip
    # the file holds no lumping: the reader is told how to read it with the same fibres
    assert "does not record --fibre-scale 4" in " ".join(said.split())
    table = tmp_path / "tester.csv"
    _run("sliver", "spectrogram", "--data", str(out), "--fibre-scale", "4", "--out", str(table))
    frame = pd.read_csv(table)
    frame = frame.rename(columns={"wavelength_m": "wavelength_cm"})
    frame["wavelength_cm"] *= 100
    frame[["wavelength_cm", "amplitude_pct", "significant"]].to_csv(table, index=False)
    dx = json.loads(_run("sliver", "diagnose", "--spectrogram", str(table), "--json"))
    assert dx["evenness"] is None
    assert all("wavelength_m" in c for c in dx["chimneys"])


def test_sliver_commands_refuse_bad_input(records, tmp_path):
    _refused("sliver", "diagnose")
    _refused("sliver", "diagnose", "--data", str(records["healthy"]), "--gauges", "44,40")
    _refused("sliver", "simulate", "--out", str(tmp_path / "a.csv"), "--staple", "wool")
    _refused("generate", "--duration", "2", "--feed-fault", "wavelength=0.5:amplitude=0.05",
             "--out", str(tmp_path / "g.csv"))  # fmt: skip
    mine = tmp_path / "x.sliver.csv"
    mine.write_text("a user's file\n")
    text = _refused("generate", "--duration", "2", "--sliver", "--out", str(tmp_path / "x.csv"))
    assert "x.sliver.csv" in text
    assert mine.read_text() == "a user's file\n"
    # a feed event beyond the sliver the record feeds would not happen (the sidecar listed
    # it); a misspelt one names every form
    for event in ("piecing=50", "missing=60-120"):
        text = _refused("generate", "--duration", "2", "--sliver", "--feed-fault", event,
                        "--out", str(tmp_path / "far.csv"))  # fmt: skip
        assert event in text and "--duration" in text and "fed" in text
    assert not list(tmp_path.glob("far*"))
    text = _refused("generate", "--duration", "2", "--sliver", "--leveller", "1,-1000",
                    "--out", str(tmp_path / "far.csv"))  # fmt: skip
    assert "-298 mm" in text and "-702" in text  # a setting every reader takes: 0-10000 mm
    text = _refused("generate", "--duration", "2", "--sliver", "--feed-fault", "mising=1-2",
                    "--out", str(tmp_path / "far.csv"))  # fmt: skip
    assert "missing=FROM_M-TO_M" in " ".join(text.split())
    bad = tmp_path / "bad.csv"
    bad.write_text("delivered_length_m,linear_density_ktex\n0.001,5\n0.002,x\n")
    _refused("sliver", "spectrogram", "--data", str(bad))


def test_reduced_physics_speeds_and_the_variance_length_curve(tmp_path):
    """`sliver simulate --reduced`: a random feed drafted at the reduced physics' speeds is a
    random sliver, so its CV(L) from `sliver spectrogram --json` follows the closed form
    (within 10 % up to 10 cm: 340 pieces or more of the 34-m record, a sampling error of
    about 4 % of the CV)."""
    out = tmp_path / "r.csv"
    _run("sliver", "simulate", "--reduced", "--duration", "8", "--fibre-scale", "20",
         "--out", str(out), "--quiet")  # fmt: skip
    got = json.loads(_run("sliver", "spectrogram", "--data", str(out), "--fibre-scale", "20",
                          "--json"))["variance_length"]  # fmt: skip
    for length, cv, ideal in zip(got["length_m"], got["cv_pct"], got["ideal_cv_pct"], strict=True):
        if length <= 0.1:
            assert cv == pytest.approx(ideal, rel=0.1), length


def test_a_simulated_sliver_too_short_to_judge_is_not_written(tmp_path: Path) -> None:
    out = tmp_path / "y.csv"
    out.write_text("precious\n")
    said = _refused("sliver", "simulate", "--quiet", "--out", str(out), "--duration", "0.01")
    assert "--duration" in said and "too short" in said
    assert out.read_text() == "precious\n"


@pytest.mark.parametrize("rate", ["10", "50", "250"])
def test_a_rate_the_sliver_cannot_be_made_at_is_refused_up_front(tmp_path: Path, rate: str) -> None:
    said = _refused("generate", "--duration", "1", "--rate", rate, "--sliver", "--quiet",
                    "--out", str(tmp_path / "g.csv"))  # fmt: skip
    assert "--rate" in said and "cannot carry the sliver" in said and "give --rate 100" in said
    assert not list(tmp_path.iterdir())


def test_a_speed_file_that_cannot_be_read_names_speeds_not_an_option_the_command_lacks(
    tmp_path: Path,
) -> None:
    table = tmp_path / "table.csv"
    table.write_text("length_m,linear_density_ktex\n"
                     + "".join(f"{(k + 0.5) * 1e-3:.4f},{5 + 0.01 * (k % 7):.3f}\n"
                               for k in range(200)))  # fmt: skip
    for args in (["sliver", "simulate", "--out", str(tmp_path / "s.csv")],
                 ["sliver", "diagnose", "--data", str(table)]):  # fmt: skip
        said = _refused(*args, "--speeds", str(table))
        assert "--speeds" in said and "--columns" not in said, said


def test_options_that_would_be_ignored_are_refused(tmp_path: Path) -> None:
    said = _refused("sliver", "simulate", "--out", str(tmp_path / "s.csv"), "--truth",
                    "--duration", "1")  # fmt: skip
    assert "--truth" in said and "--speeds is physics" in said
    table = tmp_path / "spec.csv"
    table.write_text("wavelength_cm,amplitude_pct\n1.0,0.1\n2.0,0.1\n")
    said = _refused("sliver", "diagnose", "--spectrogram", str(table), "--speeds",
                    str(tmp_path / "any.csv"))  # fmt: skip
    assert "--speeds" in said and "spectrogram table" in said
    assert not list(p for p in tmp_path.iterdir() if p.name != "spec.csv")
    # a table without significance marks: every channel counts, and the output says to give
    # the tested length; with it, no note (what it counts: test_evenness_spectrogram.py)
    out = json.loads(_run("sliver", "diagnose", "--spectrogram", str(table), "--json"))
    assert "give --tested-m" in out["notes"][0]
    out = json.loads(_run("sliver", "diagnose", "--spectrogram", str(table), "--json",
                          "--tested-m", "1000"))  # fmt: skip
    assert "notes" not in out
    said = _refused("sliver", "diagnose", "--data", str(table), "--tested-m", "100")
    assert "--tested-m" in said and "--spectrogram" in said


def test_the_diagnose_page_shows_what_the_sliver_says(records, tmp_path):
    """diagnose printed the sliver's chimneys and its element (--json had them) while its
    page, the maintenance engineer's, left all of the sliver out."""
    import re

    page = tmp_path / "diag.html"
    out = json.loads(_run("diagnose", "--model", "preset", "--data", str(records["gear"]),
                          "--healthy", str(records["healthy"]), "--report", str(page),
                          "--json"))  # fmt: skip
    sliver = out["sliver"]
    html = page.read_text()
    text = re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", html)).replace("&#x27;", "'")
    assert 'id="sliver"' in html and "What the sliver says" in text
    assert f"count {sliver['count_ktex']:.4f} ktex, CV {sliver['cv_pct']:.3f} %" in text
    for c in sliver["chimneys"]:
        assert f"{c['wavelength_m'] * 100:.3g} cm" in text and c["verdict"] in text
    assert sliver["chimneys"] and "gear B (A-B)" in text  # the run-out's gear, as printed
    assert 'id="fig-sliver-spectrogram"' in html


def test_a_records_fibre_scale_comes_from_its_sidecar(tmp_path):
    """generate --sliver --fibre-scale 4 wrote the lumping into the sidecar, and the sliver
    commands read 1: Martindale's limit halved, the index of irregularity doubled."""
    path = tmp_path / "fs4.csv"
    _run("generate", "--duration", "12", "--seed", "9", "--sliver", "--fibre-scale", "4",
         "--quiet", "--out", str(path))  # fmt: skip
    assert json.loads(path.with_suffix(".json").read_text())["sliver"]["fibre_scale"] == 4.0
    said = json.loads(_run("sliver", "spectrogram", "--data", str(path), "--json"))["evenness"]
    given = json.loads(_run("sliver", "spectrogram", "--data", str(path), "--json",
                            "--fibre-scale", "4"))["evenness"]  # fmt: skip
    plain = json.loads(_run("sliver", "spectrogram", "--data", str(path), "--json",
                            "--fibre-scale", "1"))["evenness"]  # fmt: skip
    assert said == given
    key = next(k for k in said if "martindale" in k.lower())
    assert said[key] == pytest.approx(2 * plain[key], rel=1e-9)  # sqrt(4): CV of 1/4 the fibres
    dx = json.loads(_run("sliver", "diagnose", "--data", str(path), "--json"))
    assert dx["evenness"][key] == pytest.approx(said[key], rel=1e-9)
