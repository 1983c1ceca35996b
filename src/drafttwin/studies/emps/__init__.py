"""The EMPS benchmark (Janot et al. 2019): ``drafttwin benchmark emps``, report
:mod:`drafttwin.report.emps`, data loader :mod:`drafttwin.datasets.emps`.

* :mod:`.plan`: models, tasks, seeds and each model's options on the official split;
* :mod:`.run`: every model fitted and scored through the evaluation protocol;
* :mod:`.summary`: one row per (task, model) over the seeds;
* :mod:`.physics`: the published physics as a drafttwin drive train.
"""

from drafttwin.studies.emps.physics import EmpsPhysics
from drafttwin.studies.emps.plan import EmpsConfig
from drafttwin.studies.emps.run import EmpsResult, run_benchmark

__all__ = ["EmpsConfig", "EmpsPhysics", "EmpsResult", "run_benchmark"]
