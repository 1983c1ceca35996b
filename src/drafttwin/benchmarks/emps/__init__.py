"""The EMPS benchmark (Janot et al. 2019): the published physics as a drafttwin drive train
(:mod:`.physics`), and every model fitted and scored through the evaluation protocol on the
official split (:mod:`.run`). The data loader is :mod:`drafttwin.datasets.emps`, the report
:mod:`drafttwin.report.emps`."""

from drafttwin.benchmarks.emps.physics import EmpsPhysics
from drafttwin.benchmarks.emps.run import EmpsConfig, EmpsResult, run_benchmark

__all__ = ["EmpsConfig", "EmpsPhysics", "EmpsResult", "run_benchmark"]
