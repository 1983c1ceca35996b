"""The generalisation benchmark (issue 16): ``drafttwin benchmark generalisation`` (and its
quick subset in ``drafttwin reproduce``), report :mod:`drafttwin.report.generalisation`.
Models trained at one operating point of one machine, tested where their training never went
(other speeds, start-up and stop, other draft gears, another machine) and on little data.

* :mod:`.plan`: what to run (:class:`~.plan.GeneralisationConfig`, quick and full), each
  model's options and the fits it expands to;
* :mod:`.run`: running it: records, physics, the hybrids' structure choice on the validation
  records, the fits and the accuracy floors;
* :mod:`.records`: the plant records each scenario trains and tests on;
* :mod:`.fits`: one fit scored on its test records (an executor task);
* :mod:`.summary`: the extrapolation table, learning curves, hybrid ratios and checks.
"""

from drafttwin.studies.generalisation.plan import FULL, QUICK, GeneralisationConfig, get_config
from drafttwin.studies.generalisation.run import run_benchmark

__all__ = ["FULL", "QUICK", "GeneralisationConfig", "get_config", "run_benchmark"]
