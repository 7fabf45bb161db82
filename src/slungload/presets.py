"""Training presets: named optimisation schedules (``TrainConfig`` plus ``TrainExtras``).

``paper`` is the paper's schedule, ``default`` the budget tuned for a 2-core CPU (measured in
docs/training.md), ``quick`` a smoke test. ``train(..., preset=...)`` takes a name or a
``Preset``.
"""

from __future__ import annotations

from dataclasses import dataclass

from .config import TrainConfig


@dataclass(frozen=True)
class TrainExtras:
    """Training options beyond ``config.TrainConfig`` (candidates to move into it)."""

    warmup_epochs: int = 0  # epochs of linear lr warm-up before the cosine decay
    min_lr_ratio: float = 0.0  # lr at the end of the cosine decay, as a fraction of lr
    max_time: float | None = None  # s, wall-clock budget of the run, resumed parts included
    val_windows: int | None = None  # validate on a fixed seeded subset of this size (None: all)
    max_bad_steps: int = 10  # consecutive non-finite training losses before giving up
    # Turn every training window about the vertical by a random yaw (a symmetry of the physics:
    # ``state.rotate_about_z``): the network meets each maneuver at every heading.
    augment_yaw: bool = False

    def __post_init__(self) -> None:
        if self.warmup_epochs < 0:
            raise ValueError(f"warmup_epochs must be >= 0, got {self.warmup_epochs}")
        if not 0.0 <= self.min_lr_ratio <= 1.0:
            raise ValueError(f"min_lr_ratio must be in [0, 1], got {self.min_lr_ratio}")
        if self.max_time is not None and self.max_time <= 0:
            raise ValueError(f"max_time must be > 0 s, got {self.max_time}")
        if self.val_windows is not None and self.val_windows < 1:
            raise ValueError(f"val_windows must be >= 1, got {self.val_windows}")
        if self.max_bad_steps < 1:
            raise ValueError(f"max_bad_steps must be >= 1, got {self.max_bad_steps}")


@dataclass(frozen=True)
class Preset:
    """A named optimisation schedule: ``TrainConfig`` plus ``TrainExtras``."""

    name: str
    config: TrainConfig
    extras: TrainExtras = TrainExtras()
    description: str = ""


PRESETS: dict[str, Preset] = {
    "paper": Preset(
        "paper",
        TrainConfig(
            lr=1e-4, weight_decay=0.05, batch_size=256, max_epochs=3000, patience=50, grad_clip=0.0
        ),
        description="the paper: Adam 1e-4, L2 0.05, batch 256, <= 3000 epochs, patience 50",
    ),
    # For a 2-core CPU, one thread per run, two runs side by side (measured, docs/training.md):
    # the paper-size model costs ~2.8 ms per window and training step at batch 64, so an epoch
    # of 2,048 windows plus 1,024 validation windows takes ~7 s alone and ~10 s with a second
    # run beside it; 45 epochs fit in ~8 min, and max_time caps a run at 10 min whatever the
    # machine, so three variants two at a time finish within ~20 min.
    "default": Preset(
        "default",
        TrainConfig(
            lr=1e-3,
            weight_decay=0.05,
            optimizer="adamw",
            batch_size=64,
            max_epochs=45,
            patience=12,
            windows_per_epoch=2048,
            lr_schedule="cosine",
        ),
        TrainExtras(warmup_epochs=3, min_lr_ratio=0.05, max_time=600.0, val_windows=1024),
        description="CPU budget: AdamW 1e-3, warm-up + cosine, 2048 windows/epoch, <= 10 min",
    ),
    "quick": Preset(
        "quick",
        TrainConfig(
            lr=1e-3,
            weight_decay=0.0,
            batch_size=32,
            max_epochs=2,
            patience=2,
            windows_per_epoch=128,
        ),
        TrainExtras(val_windows=64),
        description="smoke test: 2 epochs of 128 windows, seconds",
    ),
}


def get_preset(preset: str | Preset) -> Preset:
    """A preset by name (``PRESETS``), or the given ``Preset`` itself."""
    if isinstance(preset, Preset):
        return preset
    if preset not in PRESETS:
        raise ValueError(f"unknown training preset {preset!r}; choose from {sorted(PRESETS)}")
    return PRESETS[preset]
