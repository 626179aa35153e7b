"""Training a model: the training pixels (``images``), the optimization of Section 5.3 (``trainer``), its
checkpoints and stall guard, and the held-out evaluation (``evaluation``)."""
