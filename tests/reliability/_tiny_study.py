"""``python _tiny_study.py grid-search ...``: the real ``drafttwin`` CLI with a tiny study.

Registers the study plan ``tiny`` (24 s of data, one epoch) and a 2 x 3 x 2 x 2 grid of small
networks, then runs the command line: the study, its process pool and its signal handling
are the real ones, only the budget is small enough for a test. Spawned workers import this
file again as ``__mp_main__``, which only registers the plan.
"""

from dataclasses import replace

from drafttwin.studies.paper import plan

plan.STUDY_PLANS["tiny"] = replace(
    plan.STUDY_PLANS["quick"], name="tiny", data_duration_s=24.0, epochs=1, patience=None,
    grid_epochs=1, grid_train_samples=300, ablation_tests=2,
)  # fmt: skip
plan.GRID_HIDDEN = (8, 16)

if __name__ == "__main__":
    from drafttwin.cli import main

    main()
