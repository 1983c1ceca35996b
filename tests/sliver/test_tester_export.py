"""A tester's export as it comes (issue 39, item 5): read through the data layer's file checks,
its length column named or recognised, the fibres it is read with said, one line listed once."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from drafttwin.cli import app
from drafttwin.mechanics import DriveTrain
from drafttwin.sliver import Sliver, diagnose_sliver, read_sliver
from drafttwin.sliver.staple import StapleDiagram

from .test_evenness_spectrogram import count_for, random_sliver

runner = CliRunner()
POLYESTER = StapleDiagram.preset("polyester")
COARSE = StapleDiagram.gamma(38.0, 0.05, 25.0, 0.08, name="coarse")
"""Coarse fibres: 2000 of them make a 5-ktex sliver (the record of issue 39)."""
N_FIBRES = 2000.0


def _invoke(*args: str) -> tuple[int, str]:
    result = runner.invoke(app, list(args))
    return result.exit_code, result.output


@pytest.fixture(scope="module")
def export(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray]:
    """40 m of random sliver of 2000 coarse fibres (5 ktex), as a tester exports it: 1-mm
    readings under ``length_m, linear_density_ktex``."""
    rho = random_sliver(COARSE, N_FIBRES, 40.0, seed=5)
    path = tmp_path_factory.mktemp("tester") / "tester.csv"
    s = (np.arange(rho.size) + 0.5) * 1e-3
    pd.DataFrame({"length_m": s, "linear_density_ktex": rho}).to_csv(path, index=False)
    return path, rho


@pytest.mark.parametrize("command", ["spectrogram", "diagnose"])
def test_a_binary_or_damaged_file_is_refused_in_one_line(tmp_path: Path, command: str) -> None:
    junk = tmp_path / "junk.csv"
    junk.write_bytes(bytes(range(256)) * 64)
    good = tmp_path / "good.parquet"
    pd.DataFrame({"length_m": np.arange(200) * 1e-3, "x": np.ones(200)}).to_parquet(good)
    raw = good.read_bytes()
    damaged = tmp_path / "damaged.parquet"
    damaged.write_bytes(raw[:4] + b"\x00" * 300 + raw[304:])  # magic bytes kept, body broken
    for path, words in ((junk, "binary content"), (damaged, "cannot be read as Parquet")):
        code, out = _invoke("sliver", command, "--data", str(path))
        assert code == 2, out
        assert "Traceback" not in out and len(out.strip().splitlines()) == 1
        assert str(path) in out and "--data" in out and words in out


@pytest.mark.parametrize("command", ["spectrogram", "diagnose"])
def test_a_staple_file_that_cannot_be_read_is_refused_in_one_line(
    tmp_path: Path, export: tuple[Path, np.ndarray], command: str
) -> None:
    header = tmp_path / "header.csv"
    header.write_text("length_mm,fraction\n")
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    junk = tmp_path / "junk.csv"
    junk.write_bytes(bytes(range(256)) * 40)
    for path, words in ((header, "no data rows"), (empty, "file is empty"),
                        (junk, "binary content")):  # fmt: skip
        code, out = _invoke("sliver", command, "--data", str(export[0]), "--staple", str(path),
                            "--fineness-dtex", "1.5")  # fmt: skip
        assert code == 2 and "Traceback" not in out, out
        assert len(out.strip().splitlines()) == 1 and "--staple" in out and words in out


def test_a_tester_export_is_read_with_its_length_column(export) -> None:
    path, rho = export
    sl = read_sliver(path)  # length_m recognised
    assert sl.step_m == pytest.approx(1e-3) and sl.start_m == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(sl.linear_density_ktex, rho, rtol=1e-9)
    # named, in another unit, with a density column of another name
    other = path.with_name("other.csv")
    pd.DataFrame({"pos": np.arange(rho.size) * 0.1 + 0.05, "mass": rho}).to_csv(other, index=False)
    again = read_sliver(other, "mass", length_column="pos", length_unit="cm")
    assert again.step_m == pytest.approx(1e-3)
    np.testing.assert_allclose(again.linear_density_ktex, rho, rtol=1e-9)
    code, out = _invoke("sliver", "spectrogram", "--data", str(other))
    assert code == 2 and "--length-column" in out and "Traceback" not in out
    code, out = _invoke("sliver", "spectrogram", "--data", str(other), "--length-column", "pos")
    assert code == 2 and "--length-unit" in out


def test_the_report_says_which_fibres_it_assumed(export) -> None:
    """Martindale's limit follows the fibres: 2000 coarse fibres (5 ktex) read as cotton give
    a limit near 0.58 % instead of 2.24 % and an index of irregularity near 4; read with
    their own fibres the index is 1 (a random sliver); without them the JSON says that the
    cotton preset was assumed."""
    path, rho = export
    code, out = _invoke("sliver", "spectrogram", "--data", str(path), "--json")
    assert code == 0, out
    assumed = json.loads(out)
    assert assumed["fibres"]["source"] == "assumed" and assumed["fibres"]["name"] == "cotton"
    table = path.with_name("coarse.csv")
    pd.DataFrame({"length_mm": COARSE.lengths_mm, "fraction": COARSE.weights}).to_csv(table)
    code, out = _invoke("sliver", "spectrogram", "--data", str(path), "--json", "--staple",
                        str(table), "--fineness-dtex", "25", "--fineness-cv", "0.08")  # fmt: skip
    assert code == 0, out
    given = json.loads(out)
    assert given["fibres"]["source"] == "options"
    assert given["fibres"]["fibres_in_cross_section"] == pytest.approx(N_FIBRES, rel=0.01)
    limit = 100 / math.sqrt(N_FIBRES) * math.sqrt(1 + COARSE.fineness_cv**2)
    assert given["evenness"]["martindale_cv_pct"] == pytest.approx(limit, rel=0.01)
    assert given["evenness"]["index_of_irregularity"] == pytest.approx(1.0, abs=0.04)
    assert assumed["evenness"]["martindale_cv_pct"] == pytest.approx(0.58, abs=0.01)
    assert assumed["evenness"]["index_of_irregularity"] > 3.5
    code, out = _invoke("sliver", "spectrogram", "--data", str(path))
    assert "fibres assumed" in out


def test_a_plant_record_is_read_with_the_fibres_it_was_made_of(tmp_path: Path) -> None:
    from drafttwin.sliver.record import sliver_beside
    from drafttwin.sliver.staple import resolve_fibres

    rho = random_sliver(POLYESTER, N_FIBRES, 2.0, seed=1)
    sl = Sliver(rho, 1e-3)
    data = tmp_path / "rec.sliver.csv"
    sl.write(data)
    (tmp_path / "rec.csv").write_text("time,front\n0,1\n")
    sidecar = {"files": {"sliver": data.name},
               "sliver": {"delivery_sensor": {"averaging_mm": 5.0},
                          "staple": {**POLYESTER.describe(), "fineness_dtex": 1.2}}}  # fmt: skip
    (tmp_path / "rec.json").write_text(json.dumps(sidecar))
    beside = sliver_beside(tmp_path / "rec.csv")
    assert beside is not None
    fibres = resolve_fibres(None, beside.staple)
    assert fibres.source == "record" and fibres.staple.fineness_dtex == 1.2
    np.testing.assert_array_equal(fibres.staple.lengths_mm, POLYESTER.lengths_mm)
    assert resolve_fibres(StapleDiagram.preset("cotton"), beside.staple).source == "options"


def test_a_line_in_two_adjacent_channels_is_listed_once() -> None:
    """A 3 % line halfway between two periodogram bins that straddle a channel edge leaks
    into both channels; it is one chimney, its amplitude the line's."""
    step, n = 0.002, 250_000
    edge = 0.01 * 2 ** (83.5 / 10)  # the edge between channels 83 and 84 (3.26 m)
    k = math.floor(n * step / edge) + 0.5  # the line sits between bins k - 1/2 and k + 1/2
    lam = n * step / k
    s = (np.arange(n) + 0.5) * step
    rng = np.random.default_rng(2)
    rho = 5.0 * (1 + 0.03 * np.sin(2 * np.pi * s / lam) + 0.01 * rng.standard_normal(n))
    cotton = StapleDiagram.preset("cotton")
    dx = diagnose_sliver(Sliver(rho, step, staple=cotton), DriveTrain.preset("fa320a"), cotton)
    near = [c for c in dx.causes if abs(math.log(c.wavelength_m / lam)) < 0.05]
    assert len(near) == 1
    assert near[0].wavelength_m == pytest.approx(lam, rel=2e-3)
    assert near[0].excess_pct == pytest.approx(3.0, rel=0.03)
    assert len(near[0].extra["channels_m"]) == 2


def test_the_export_has_the_count_of_its_fibres(export) -> None:
    assert export[1].mean() == pytest.approx(count_for(COARSE, N_FIBRES), rel=0.01)


def test_a_length_unit_against_the_column_name_is_refused(
    export: tuple[Path, np.ndarray],
) -> None:
    code, out = _invoke("sliver", "spectrogram", "--data", str(export[0]), "--length-unit", "mm")
    assert code == 2 and "Traceback" not in out, out
    assert "says its lengths are in m, but --length-unit says mm" in " ".join(out.split())
    code, out = _invoke("sliver", "spectrogram", "--data", str(export[0]), "--length-unit", "m",
                        "--json")  # fmt: skip
    assert code == 0 and json.loads(out)["evenness"]["length_m"] > 39


def test_a_tester_export_that_is_not_read_as_numbers_says_why(tmp_path: Path) -> None:
    s = (np.arange(200) + 0.5) * 1e-3
    rho = 5.0 + 0.01 * np.sin(s * 50)
    comma = tmp_path / "comma.csv"
    comma.write_text("length_m;linear_density_ktex\n"
                     + "".join(f"{a:.4f};{b:.5f}\n".replace(".", ",") for a, b in zip(s, rho, strict=True)))  # fmt: skip
    units = tmp_path / "units.csv"
    units.write_text("length_m,linear_density_ktex\nm,ktex\n"
                     + "".join(f"{a:.4f},{b:.5f}\n" for a, b in zip(s, rho, strict=True)))  # fmt: skip
    deviation = tmp_path / "deviation.csv"
    deviation.write_text("length_m,dev_pct\n"
                         + "".join(f"{a:.4f},{(b - 5) * 20:.4f}\n" for a, b in zip(s, rho, strict=True)))  # fmt: skip
    for path, words in ((comma, "a decimal comma"), (units, "a units row below the header"),
                        (deviation, "is no density")):  # fmt: skip
        code, out = _invoke("sliver", "spectrogram", "--data", str(path))
        assert code == 2 and "Traceback" not in out, out
        assert words in " ".join(out.split()), out


def test_a_density_is_read_in_the_unit_its_column_names(export, tmp_path: Path) -> None:
    """A column in tex was read as ktex ("count 5019 ktex"); tex under a ktex name, or one
    broken cell of 1e300 ("CV inf %"), passed without a word."""
    path, rho = export
    frame = pd.read_csv(path)
    tex = tmp_path / "tex.csv"
    frame.assign(linear_density_ktex=rho * 1000).rename(
        columns={"linear_density_ktex": "linear_density_tex"}).to_csv(tex, index=False)  # fmt: skip
    assert read_sliver(tex).count_ktex == pytest.approx(float(np.mean(rho)), rel=1e-9)
    assert read_sliver(path).count_ktex == pytest.approx(float(np.mean(rho)), rel=1e-9)
    wrong = tmp_path / "wrong.csv"
    frame.assign(linear_density_ktex=rho * 1000).to_csv(wrong, index=False)
    broken = tmp_path / "broken.csv"
    cells = rho.copy()
    cells[100] = 1e300
    frame.assign(linear_density_ktex=cells).to_csv(broken, index=False)
    for bad, words in ((wrong, "mean density 5"), (wrong, "(in tex, not ktex?)"),
                       (broken, "row 101 (line 102): density 1e+300 is"),
                       (broken, "a broken cell, not a thick place")):  # fmt: skip
        code, out = _invoke("sliver", "spectrogram", "--data", str(bad))
        assert code == 2 and "Traceback" not in out, out
        assert words in " ".join(out.split()), out
