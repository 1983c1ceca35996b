"""The fault benchmark: ``drafttwin benchmark faults``, report
:mod:`drafttwin.report.faults_bench` (method in docs/faults.md). Seeded faulty and healthy
plant records, the twin's diagnosis and baselines scored as fault-diagnosis benchmarks do.

* :mod:`.plan`: the records (tuning, faults, healthy), each a task;
* :mod:`.run`: the records in parallel, then the scores;
* :mod:`.score`: the detectors run over every record's features and scored per method; it
  is the benchmark's summary too (there is no separate ``summary.py``: the scores are the
  tables);
* :mod:`.learned`: the learned residuals (data-driven, hybrid) beside the physics;
* :mod:`.sliver`: the sliver variant (``--sliver``), its own plan, run and score.
"""

from drafttwin.studies.faults.run import run_benchmark

__all__ = ["run_benchmark"]
