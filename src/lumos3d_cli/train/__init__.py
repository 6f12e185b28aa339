"""Training: configuration, trainer, distributed set-up, checkpoints."""
