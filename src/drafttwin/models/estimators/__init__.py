"""The estimators: their common base (parameters, checks, save/load), the baselines
(mechanistic, persistence), the data-driven GRU/LSTM (NARX in a simulation), the hybrids
(parallel, MD-S-L and its ablations), what they are built from (networks, input windows,
scalers, the task, the hyperparameter rules) and how a hybrid chooses on validation data
(accumulation, the blocked folds that judge its correction). Import from the modules
(``drafttwin.models.estimators.hybrid``) or from :mod:`drafttwin.models`."""
