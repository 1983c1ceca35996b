"""The paper's study on one data set: preparation, grid search, comparison, ablation over
repeated tests (:mod:`drafttwin.experiments.study`), run through :mod:`drafttwin.execution`."""
