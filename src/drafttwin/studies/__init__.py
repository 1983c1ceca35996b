"""The studies: what drafttwin measures and reports, each a subpackage of the same shape
where it fits (``plan.py``: what to run; ``run.py``: running it; ``summary.py``: tables from
the results), its report section under :mod:`drafttwin.report` and its CLI command.

* :mod:`.paper`: the paper's study on one data set (``drafttwin reproduce``);
* :mod:`.emps`: the EMPS benchmark on real measurements (``drafttwin benchmark emps``);
* :mod:`.faults`: the fault-diagnosis benchmark (``drafttwin benchmark faults``);
* :mod:`.generalisation`: where the physics pays (``drafttwin benchmark generalisation``);
* :mod:`.calibration_accuracy` and :mod:`.calibration_bias`: the calibration against the
  plant's true machine and where its test bias comes from (``python -m``; docs/calibration.md);
* :mod:`.accuracy_limits`: the accuracy floor of the default data set (``python -m``).

Timings are not here: they are the scripts of the top-level ``benchmarks/`` folder.
"""
