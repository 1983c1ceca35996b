"""Model files: one ``torch.save`` file per fitted model, read back with
``weights_only=True`` and checked field by field (:mod:`.modelfile`)."""
