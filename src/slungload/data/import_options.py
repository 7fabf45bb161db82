"""The options of ``slungload import`` (``importing.import_logs``), one frozen record: the
thrust map, the gaps, the resampling, the split and the consistency checks (``resample`` and
``importing`` read them; defaults here only)."""

from __future__ import annotations

from dataclasses import dataclass, field

from .consistency import ConsistencyLimits
from .split import WINDOW_STEPS


@dataclass(frozen=True)
class ImportOptions:
    """How logs become flights (the steps are described in ``resample``'s docstring)."""

    hover_throttle: float | None = None  # None: the log's own (ULog), else an error if needed
    newtons_per_throttle: float | None = None  # N per unit throttle, instead of the hover map
    max_gap: float = 0.1  # s, longest time a stream may go without a sample
    on_gap: str = "split"  # "split" the flight at a longer gap, or "error"
    min_duration: float = 1.0  # s, shorter pieces are dropped
    commands: str = "hold"  # "hold" the last set-point, or "linear"
    split: str = "seeded"  # "seeded" draw by recording, "train" (all), or "blocks" in time
    block_gap: int = WINDOW_STEPS  # steps left out between time blocks, at least M + N
    seed: int = 0
    force: bool = False  # import flights outside the consistency limits (noted, recorded)
    limits: ConsistencyLimits = field(default_factory=ConsistencyLimits)

    def __post_init__(self) -> None:
        if self.hover_throttle is not None and not 0.0 < self.hover_throttle <= 1.0:
            raise ValueError(f"hover throttle must be in (0, 1], got {self.hover_throttle}")
        if self.newtons_per_throttle is not None:
            if not self.newtons_per_throttle > 0:
                raise ValueError(
                    f"newtons per throttle must be > 0 N, got {self.newtons_per_throttle}"
                )
            if self.hover_throttle is not None:
                raise ValueError("give the hover throttle or the newtons per throttle, not both")
        if not self.max_gap > 0:
            raise ValueError(f"max gap must be > 0 s, got {self.max_gap}")
        if self.block_gap < 1:
            raise ValueError(f"block gap must be >= 1 step, got {self.block_gap}")
        if self.min_duration < 0:
            raise ValueError(f"min duration must be >= 0 s, got {self.min_duration}")
        for name, known in (
            ("on_gap", ("split", "error")),
            ("commands", ("hold", "linear")),
            ("split", ("seeded", "train", "blocks")),
        ):
            if getattr(self, name) not in known:
                raise ValueError(f"{name} must be one of {known}, got {getattr(self, name)!r}")
