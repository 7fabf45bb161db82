"""Training: ``trainer.train`` (one entry), the Lightning module and loss (``module``), batches
and yaw augmentation (``batches``), named schedules (``presets``), and the Lightning
workarounds for atomic checkpoints, signals and resumable logs (``runtime``).

Nothing is imported here, so that ``training.presets`` (read by the CLI's help) does not pull
in Lightning.
"""
