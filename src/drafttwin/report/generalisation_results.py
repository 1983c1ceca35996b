"""Figures of the generalisation benchmark from its results JSON, as markdown.

    drafttwin benchmark generalisation --out gen_out --workers 2     # the full run
    python -m drafttwin.report.generalisation_results gen_out/generalisation_results.json

Prints the extrapolation table, the learning curves, the hybrid/GRU ratios, the structure
choice, the floors and the run's wall times as markdown; writes them to
docs/generalisation-results.md (``--markdown``) and the headline figures to
benchmarks/results/generalisation.json, both below the folder it is run from.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from drafttwin._io import write_text_atomic
from drafttwin.report import generalisation as tables
from drafttwin.studies.figures import write_results

DOCS = Path("docs") / "generalisation-results.md"


def markdown(head: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(c or " " for c in r) + " |" for r in rows]
    return "\n".join(lines)


def headline(doc: dict[str, Any]) -> list[dict[str, Any]]:
    """Per scenario and task, each model's RMSE averaged over rollers (mean over seeds)."""
    out = []
    groups: dict[tuple[str, str, str], list[float]] = {}
    for r in doc["extrapolation"]:
        if r["rmse"]["mean"] is not None:
            groups.setdefault((r["scenario"], r["task"], r["model"]), []).append(r["rmse"]["mean"])
    for (scenario, task, model), values in sorted(groups.items()):
        out.append({"figure": f"{task} RMSE, {scenario}, {model} (mean over rollers)",
                    "value": sum(values) / len(values), "unit": "rpm"})  # fmt: skip
    for key, value in doc["timings"].items():
        out.append({"figure": f"wall time: {key}", "value": value, "unit": "s"})
    return out


def run_label(cfg: dict[str, Any]) -> str:
    """``full`` or ``quick`` when the run used that configuration; else what was changed."""
    from dataclasses import asdict

    from drafttwin.studies.generalisation import FULL, QUICK

    base = asdict(QUICK if cfg["name"] == "quick" else FULL)
    changed = [k for k, v in base.items() if k != "workers" and json.dumps(v) != json.dumps(cfg[k])]
    return cfg["name"] if not changed else f"reduced: {', '.join(changed)} changed"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("results", type=Path, help="generalisation_results.json")
    parser.add_argument("--markdown", type=Path, default=DOCS, help="markdown file to write")
    args = parser.parse_args()
    doc = json.loads(args.results.read_text(encoding="utf-8"))
    cfg = doc["config"]
    parts = [
        "<!-- written by python -m drafttwin.report.generalisation_results from the benchmark's JSON -->",
        f"# Generalisation benchmark: measured figures ({run_label(cfg)})",
        f"{cfg['seeds']} seed(s), training lengths {cfg['train_lengths_s']} s, test records "
        f"{cfg['test_s']:g} s, network {cfg['layers']} x {cfg['hidden']}, window {cfg['window']}, "
        f"at most {cfg['epochs']} epochs (patience {cfg['patience']}), stride {cfg['stride']}, "
        f"{cfg['workers']} worker(s); wall time {doc['timings']['total_s']:.0f} s. "
        "RMSE in rpm, mean ± std over seeds.",
        "## Hybrid structure chosen on the validation records (steady at the training set-point, at +15 % and -15 %, speed change from +15 %)",
        markdown(*tables.structure_rows(doc)),
        "## Checks", "\n".join(f"* {line}" for line in tables.check_lines(doc)),
        "## Extrapolation table: free-run simulation", markdown(*tables.extrapolation_rows(doc, "simulation")),
        "## Extrapolation table: one-step prediction", markdown(*tables.extrapolation_rows(doc, "prediction")),
        "## Hybrid RMSE / GRU RMSE (same seed, full training length)", markdown(*tables.ratio_rows(doc)),
        "## Learning curves (little-data test record)", markdown(*tables.learning_rows(doc)),
        "## One-step floor (oracle)", markdown(*tables.floor_rows(doc)),
    ]  # fmt: skip
    text = "\n\n".join(parts) + "\n"
    print(text)
    write_text_atomic(args.markdown, text)
    print(f"wrote {args.markdown}")
    print(f"wrote {write_results('generalisation', headline(doc))}")


if __name__ == "__main__":
    main()
