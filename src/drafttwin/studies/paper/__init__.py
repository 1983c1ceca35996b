"""The paper's study on one data set: ``drafttwin reproduce`` (and ``drafttwin grid-search``,
its grid search alone), report sections :mod:`drafttwin.report.overview`,
:mod:`drafttwin.report.comparison` and :mod:`drafttwin.report.studies` (written by
:mod:`drafttwin.report.writer`).

* :mod:`.plan`: the study plans (quick, standard, paper: :class:`~.plan.StudyPlan`) and the
  grid of Fig. 7;
* :mod:`.run`: the stages (data, grid search, comparison, ablation over repeated tests) as
  executor tasks (:mod:`drafttwin.execution`), resumable;
* :mod:`.prepare`: the prepared data every task reads; :mod:`.tasks`: the tasks themselves.

There is no ``summary.py``: the tables are made from ``results.json`` by
:mod:`drafttwin.report.tables`, which the report and its CSV files share.
"""
