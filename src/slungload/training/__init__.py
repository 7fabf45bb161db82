"""Training: ``trainer.train`` (one entry, taking a ``run_config.RunConfig``), the Lightning
module and loss (``module``), batches and yaw augmentation (``batches``), system
identification (``identify``), and the Lightning workarounds for atomic checkpoints, signals
and resumable logs (``runtime``). The named schedules are ``run_config.PRESETS``.

Nothing is imported here, so that importing a module of this package loads only what it needs.
"""
