"""The generalisation benchmark (issue 16): models trained at one operating point of one
machine, tested where their training never went (other speeds, start-up and stop, other draft
gears, another machine) and on little data (:mod:`.run`); the plant records are
:mod:`.records`, the accuracy floor :mod:`.floors`, the summaries :mod:`.summary`. The report
is :mod:`drafttwin.report.generalisation`."""

from drafttwin.benchmarks.generalisation.run import (
    FULL,
    QUICK,
    GeneralisationConfig,
    get_config,
    run_benchmark,
)

__all__ = ["FULL", "QUICK", "GeneralisationConfig", "get_config", "run_benchmark"]
