"""The study report: files and CSV tables, a self-contained page that renders in a browser,
and agreement statements computed from the numbers."""

from __future__ import annotations

import copy
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from drafttwin import ROLLERS
from drafttwin.report import agreement, write_report
from drafttwin.report.fmt import count_text, span
from drafttwin.report.studies import agreement_section

from ._results_fixture import build

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
N_FIGURES = 6  # the headline figure, RMSE, predictions, residuals, grid, ablation
HOSTILE = "<b>raw</b> & <script>alert(1)</script>"


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, dict[str, Path]]:
    results, predictions = build(n_test=1500)
    results["findings"].append(HOSTILE)
    out = tmp_path_factory.mktemp("report")
    return results, write_report(out, results, predictions)


def _csv(paths: dict[str, Path], name: str) -> pd.DataFrame:
    return pd.read_csv(paths[name])


def test_writes_every_file_and_nothing_else(report: tuple[dict, dict[str, Path]]) -> None:
    _, paths = report
    assert set(paths) == {"report", "table2", "metrics", "table3", "table3_summary", "grid"}
    folder = paths["report"].parent
    names = sorted(p.name for p in folder.iterdir())
    assert names == sorted(p.name for p in paths.values())  # no temporary files left behind


def test_table2_sits_beside_the_paper(report: tuple[dict, dict[str, Path]]) -> None:
    results, paths = report
    t2 = _csv(paths, "table2")
    models = results["comparison"]["models"] + results["comparison"]["extra"]
    assert len(t2) == len(models) * len(ROLLERS)
    assert {"model", "roller", "max_rel_err_pct", "mean_rel_err_pct", "paper_max_rel_err_pct",
            "paper_mean_rel_err_pct"} <= set(t2.columns)  # fmt: skip
    row = t2[(t2.model == "md-s-l") & (t2.roller == "front")].iloc[0]
    assert row.paper_max_rel_err_pct == pytest.approx(0.051)
    ours = results["comparison"]["metrics"]["md-s-l"]["front"]["mean_rel_err_pct"]
    assert row.mean_rel_err_pct == pytest.approx(ours, rel=1e-9)
    assert t2[t2.model == "persistence"].paper_mean_rel_err_pct.isna().all()
    assert t2[t2.model == "md-s-l+d"].extra.all()


def test_metric_ablation_and_grid_tables(report: tuple[dict, dict[str, Path]]) -> None:
    results, paths = report
    metrics = _csv(paths, "metrics")
    assert len(metrics) == 6 * len(ROLLERS)
    for col in ("rmse", "nrmse", "skill", "mean_rel_err_pct", "max_rel_err_pct",
                "accuracy_pct", "rmse_floor", "rmse_vs_true", "sensor_rmse", "true_error_ratio",
                "rel_threshold"):  # fmt: skip
        assert metrics[col].notna().all(), col
    assert (metrics.unit == "rpm").all() and (metrics.n_rel_excluded == 0).all()
    t3 = _csv(paths, "table3")
    n_tests = len(results["ablation"]["seeds"])
    assert len(t3) == 3 * n_tests * len(ROLLERS)
    assert set(t3.variant) == {"md-s-l", "md-l", "md-s"}
    first = t3[(t3.variant == "md-l") & (t3.test == 1) & (t3.roller == "second")].iloc[0]
    assert first.paper_accuracy_pct == pytest.approx(98.55)
    assert (t3.unit == "rpm").all() and t3.rmse.notna().all()
    summary = _csv(paths, "table3_summary")
    assert len(summary) == 3 * len(ROLLERS)
    assert {"mean", "std", "min", "max", "paper_mean", "paper_std"} <= set(summary.columns)
    grid = _csv(paths, "grid")
    assert len(grid) == 36
    assert list(grid.columns[:7]) == ["network", "lr", "hidden", "layers", "val_loss", "epochs",
                                      "wall_s"]  # fmt: skip
    assert grid.groupby("network").best.sum().to_dict() == {"gru": 1, "lstm": 1}


def test_page_is_self_contained_and_escaped(report: tuple[dict, dict[str, Path]]) -> None:
    _, paths = report
    text = paths["report"].read_text(encoding="utf-8")
    assert "<link" not in text and 'src="http' not in text and "url(" not in text
    assert text.count('<img src="data:image/png;base64,') == N_FIGURES
    assert HOSTILE not in text and "&lt;b&gt;raw&lt;/b&gt; &amp; &lt;script&gt;" in text
    assert "plant emulator, not a real FA320A" in text
    assert "Table 2 gives the same model" in text  # the paper-inconsistency note
    assert "RMSE (rpm)" in text and "RMSE vs true (rpm)" in text and "RMSE in rpm" in text
    assert "Relative errors omitted" not in text


class _Dom(HTMLParser):
    """Collects the body's attributes, element ids and the number of images."""

    def __init__(self) -> None:
        super().__init__()
        self.body: dict[str, str | None] = {}
        self.ids: set[str] = set()
        self.images = 0

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        d = dict(attrs)
        if tag == "body":
            self.body = d
        if tag == "img":
            self.images += 1
        if d.get("id"):
            self.ids.add(str(d["id"]))


def _chromium() -> str | None:
    return next((p for n in CHROMIUM_NAMES if (p := shutil.which(n))), None)


def test_renders_in_headless_chromium(report: tuple[dict, dict[str, Path]], tmp_path: Path) -> None:
    browser = _chromium()
    if browser is None:
        pytest.skip("no chromium binary found (.ci/run installs it)")
    _, paths = report
    cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
           "--no-first-run", "--disable-background-networking", "--disable-component-update",
           "--disable-sync", f"--user-data-dir={tmp_path / 'profile'}",
           "--virtual-time-budget=5000", "--dump-dom", paths["report"].resolve().as_uri()]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=90, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    dom = _Dom()
    dom.feed(done.stdout)
    assert dom.images == N_FIGURES
    assert dom.body.get("data-images-total") == str(N_FIGURES)
    assert dom.body.get("data-images-loaded") == str(N_FIGURES)
    assert {"table2", "metrics", "table3", "differences", "agreement", "grid-best"} <= dom.ids


def _set(results: dict, model: str, key: str, values: list[float]) -> None:
    for r, v in zip(ROLLERS, values, strict=True):
        results["comparison"]["metrics"][model][r][key] = v


def _claim(results: dict, key: str) -> agreement.Claim:
    return next(c for c in agreement.claims(results) if c.key == key)


def test_agreement_follows_the_numbers() -> None:
    results, _ = build(n_test=400)
    before = _claim(results, "md-s-l>parallel")
    assert before.verdict == agreement.AGREES
    assert "lower RMSE on all four rollers" in before.ours
    flipped = copy.deepcopy(results)
    metrics = flipped["comparison"]["metrics"]
    metrics["md-s-l"], metrics["parallel"] = metrics["parallel"], metrics["md-s-l"]
    after = _claim(flipped, "md-s-l>parallel")
    assert after.verdict == agreement.DISAGREES
    assert "lower RMSE on no roller" in after.ours
    assert after.paper == before.paper  # the paper's side does not move
    html_before, html_after = str(agreement_section(results)), str(agreement_section(flipped))
    assert "lower RMSE on all four rollers" in html_before
    assert "lower RMSE on no roller" in html_after


def test_agreement_partly_and_ablation_spread() -> None:
    results, _ = build(n_test=400)
    rmse = [results["comparison"]["metrics"]["md-s-l"][r]["rmse"] for r in ROLLERS]
    _set(results, "parallel", "rmse", [rmse[0] - 0.01, *(x + 0.01 for x in rmse[1:])])
    claim = _claim(results, "md-s-l>parallel")
    assert "lower RMSE on 3 of 4 (second, third, back)" in claim.ours
    assert claim.verdict == agreement.AGREES  # the verdict follows the paper's metric
    _set(results, "parallel", "mean_rel_err_pct", [0.0, 0.0, 1.0, 1.0])
    claim = _claim(results, "md-s-l>parallel")
    assert "same direction as the paper on 2 of 4 (third, back)" in claim.ours
    assert claim.verdict == agreement.PARTLY
    gru = _claim(results, "md-s-l>gru")  # the paper's own Table 2: MD-S-L lower on second only
    assert gru.verdict == agreement.PARTLY and "on 1 of 4 (second)" in gru.paper
    for d in results["ablation"]["differences"]:
        d["larger_than_spread"] = d["a"] == "md-s-l" and d["b"] == "md-s" and d["roller"] == "back"
    assert _claim(results, "md-s-l>md-s").verdict == agreement.PARTLY
    assert _claim(results, "md-l>md-s").verdict == agreement.DISAGREES
    assert "MD-S-L on all four rollers" in _claim(results, "skill").ours
    _set(results, "md-s-l", "skill", [-0.1, -0.2, 0.05, -0.3])
    assert "MD-S-L on 1 of 4 (third)" in _claim(results, "skill").ours


def test_report_without_truth_or_extra_variants(tmp_path: Path) -> None:
    """Real data: no true speed (no floor, no sensor error), no extra variants, no findings."""
    results, predictions = build(n_test=300)
    results["comparison"]["extra"] = []
    results.pop("findings")
    results["ablation"].pop("spread_definition")
    for d in results["ablation"]["differences"]:
        d.pop("welch_p")
    results["data"]["plant_summary"] = []
    for model in results["comparison"]["metrics"].values():
        for m in model.values():
            for key in ("rmse_floor", "rmse_vs_true", "sensor_rmse", "true_error_ratio"):
                m[key] = None
    predictions = predictions.drop(columns=[f"true_{r}" for r in ROLLERS])
    paths = write_report(tmp_path, results, predictions)
    text = paths["report"].read_text(encoding="utf-8")
    assert "not a real FA320A" not in text and "floor unknown: no true speed" in text
    assert "encoder error (measured vs true)" not in text
    assert "Welch t-test" not in text and "as computed by the study" in text
    assert np.isnan(pd.read_csv(paths["metrics"]).rmse_floor).all()


def test_units_and_omitted_relative_errors_come_from_the_results(tmp_path: Path) -> None:
    results, predictions = build(n_test=300)
    for model in results["comparison"]["metrics"].values():
        for r, m in model.items():
            m["unit"] = "m"
            if r == "third":
                m["rel_note"] = "signal crosses zero: relative errors are not defined"
                m["mean_rel_err_pct"] = m["max_rel_err_pct"] = m["accuracy_pct"] = None
    text = write_report(tmp_path, results, predictions)["report"].read_text(encoding="utf-8")
    assert "RMSE (m)" in text and "RMSE in m;" in text and "RMSE (rpm)" not in text
    assert "Relative errors omitted: third (signal crosses zero" in text
    floor = _claim(results, "floor").ours
    assert " m = " in floor and "rpm" not in floor
    assert (pd.read_csv(tmp_path / "table3.csv").unit == "m").all()


def test_formatting_helpers() -> None:
    assert span([-1.989, -0.185], 3) == "−1.989 to −0.185"
    assert span([0.011, 0.049, float("nan")], 3, " %") == "0.011–0.049 %"
    assert count_text(list(ROLLERS)) == "all four rollers"
    assert count_text([]) == "no roller"
    assert count_text(["front", "back"]) == "2 of 4 (front, back)"


def test_limits_claim_names_the_floor_and_a_model_below_it() -> None:
    """Every roller's best RMSE against its floor and the best estimate of the true speed
    against the encoders' error, from the numbers; a model below its floor is called out."""
    results, _ = build(n_test=300)
    metrics = results["comparison"]["metrics"]
    text = _claim(results, "floor").ours
    for r in ROLLERS:
        best = min(results["comparison"]["models"], key=lambda m: metrics[m][r]["rmse"])
        m = metrics[best][r]
        assert f"{r}: {agreement.label(best)} {m['rmse']:.3f} rpm" in text
        assert f"{m['rmse'] / m['rmse_floor']:.2f} × the floor {m['rmse_floor']:.3f}" in text
    assert "BELOW" not in text and "× the encoder's error" in text
    metrics["gru"]["back"]["rmse"] = 0.5 * metrics["gru"]["back"]["rmse_floor"]
    assert (
        "(BELOW the floor: GRU (data-driven); the floor is wrong)" in _claim(results, "floor").ours
    )


@pytest.mark.parametrize(("lo", "hi", "expected"), [
    (0.35, 0.52, ["0.4", "0.5"]),  # had been 0.35, 0.375, ... 0.525: labels run together
    (3.1, 3.4, ["3.2", "3.4"]),
    (0.35, 2.52, ["0.5", "0.7", "1", "1.5", "2"]),  # a span holding its own ticks: as before
])  # fmt: skip
def test_a_narrow_log_axis_gets_a_few_plain_ticks(
    lo: float, hi: float, expected: list[str]
) -> None:
    import matplotlib.pyplot as plt

    from drafttwin.report.figures import log_axis_plain

    fig, ax = plt.subplots(figsize=(3, 3))
    ax.set_yscale("log")
    ax.plot([0, 1], [lo, hi])
    log_axis_plain(ax.yaxis)
    fig.canvas.draw()
    y0, y1 = ax.get_ylim()
    shown = [t.get_text() for t in ax.get_yticklabels() if y0 <= t.get_position()[1] <= y1]
    plt.close(fig)
    assert shown == expected
