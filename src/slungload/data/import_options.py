"""The options of ``slungload import`` (``importing.import_logs``), one frozen record: the
thrust map, the gaps, the resampling, the split and the consistency checks (``resample`` and
``importing`` read them; defaults here only); and ``SecondLog``, a second log that gives some
streams of every flight (``alignment``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .consistency import ConsistencyLimits
from .split import WINDOW_STEPS

# s: stamps' rounding: a sample stamped this close after a grid instant counts as at it, and a
# time step this much over its --max-gap is no gap (a clean 10 Hz stream's steps from
# nanosecond stamps come out as 0.1000000001 s)
STAMP_EPS = 1e-6
# streams a per-stream --max-gap names (readers.logs.ROLES, light here), and the groups that
# name several: a bag's pose topic gives position and attitude, its command rates and thrust
GAP_STREAMS = ("position", "attitude", "velocity", "load", "rates", "thrust")
GAP_GROUPS = {"pose": ("position", "attitude"), "commands": ("rates", "thrust")}


@dataclass(frozen=True)
class ImportOptions:
    """How logs become flights (the steps are described in ``resample``'s docstring)."""

    hover_throttle: float | None = None  # None: the log's own (ULog), else an error if needed
    newtons_per_throttle: float | None = None  # N per unit throttle, instead of the hover map
    max_gap: float = 0.1  # s, longest time a stream may go without a sample
    max_gaps: tuple[tuple[str, float], ...] = ()  # (stream, s): its own max_gap (GAP_STREAMS)
    dropout_steps: float = 3.0  # a step this many times a stream's median, interpolated: noted
    on_gap: str = "split"  # "split" the flight at a longer gap, or "error"
    min_duration: float = 1.0  # s, shorter pieces are dropped
    commands: str = "hold"  # "hold" the last set-point, or "linear"
    split: str = "seeded"  # "seeded" draw by recording, "train" (all), or "blocks" in time
    block_gap: int = WINDOW_STEPS  # steps left out between time blocks, at least M + N
    split_tolerance: float = 0.1  # share of the windows a seeded split may miss by, unnoted
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
        object.__setattr__(self, "max_gaps", tuple((str(r), float(g)) for r, g in self.max_gaps))
        for role, gap in self.max_gaps:
            if role not in GAP_STREAMS:
                raise ValueError(
                    f"--max-gap {role}=...: unknown stream {role!r}; streams: "
                    f"{', '.join(GAP_STREAMS)} (or {groups_text()})"
                )
            if not gap > 0:
                raise ValueError(f"max gap of the {role} must be > 0 s, got {gap}")
        if not self.dropout_steps > 1:
            raise ValueError(f"dropout steps must be > 1, got {self.dropout_steps}")
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

    def gap(self, role: str) -> float:
        """s, the longest time the stream ``role`` may go without a sample: its own
        ``max_gaps`` entry (the last given), else ``max_gap``."""
        own = [g for r, g in self.max_gaps if r == role]
        return own[-1] if own else self.max_gap

    def gaps_record(self) -> dict[str, float]:
        """Each stream's max gap that differs from ``max_gap``, for ``vehicle.json``."""
        return {r: self.gap(r) for r in GAP_STREAMS if self.gap(r) != self.max_gap}


def groups_text() -> str:
    """``pose: position + attitude; commands: rates + thrust``."""
    return "; ".join(f"{k}: {' + '.join(v)}" for k, v in GAP_GROUPS.items())


def parse_gap(text: str) -> list[tuple[str, float]]:
    """One ``--max-gap`` value: ``S`` (every stream: the pair ``("", S)``) or
    ``STREAM[,STREAM]=S`` (``GAP_STREAMS``, or a group of ``GAP_GROUPS``); ``:`` may stand for
    ``=``. A ``ValueError`` names what is wrong."""
    text = text.strip()
    head, sep, value = text.replace(":", "=").rpartition("=")
    try:
        gap = float(value)
    except ValueError:
        raise ValueError(
            f"expected S or STREAM=S (s; STREAM one of {', '.join(GAP_STREAMS)}, "
            f"{', '.join(GAP_GROUPS)}), got {text!r}"
        ) from None
    if not sep:
        return [("", gap)]
    out = []
    for name in (n.strip() for n in head.split(",")):
        roles = GAP_GROUPS.get(name, (name,))
        if roles[0] not in GAP_STREAMS:
            raise ValueError(
                f"unknown stream {name!r} in {text!r}; streams: {', '.join(GAP_STREAMS)} "
                f"(or {groups_text()})"
            )
        out += [(r, gap) for r in roles]
    return out


ROTATIONS = ("yaw", "full")


@dataclass(frozen=True)
class SecondLog:
    """A second log (typically motion capture: a bag or a CSV) that gives ``roles`` of every
    flight, aligned in time and frame to each first log on the vehicle track both hold
    (``alignment.align_tracks``; the tolerances are ``ConsistencyLimits.align_*``)."""

    path: Path
    roles: tuple[str, ...] = ("load",)  # streams taken from it (readers.logs.ROLES)
    mapping: dict[str, Any] | None = field(default=None, compare=False)  # None: the import's
    time_offset: float | None = None  # s added to its stamps for the first's clock; None: fit
    rotation: str = "yaw"  # its frame differs by a rotation about z ("yaw") or any ("full")

    def __post_init__(self) -> None:
        from .readers.logs import ROLES  # numpy: only once a second log is named

        object.__setattr__(self, "path", Path(self.path).expanduser())
        object.__setattr__(self, "roles", tuple(self.roles))
        unknown = [r for r in self.roles if r not in ROLES]
        if not self.roles or unknown:
            raise ValueError(
                f"streams from the second log must be some of {', '.join(ROLES)}; got "
                f"{', '.join(self.roles) or 'none'}"
            )
        if self.time_offset is not None and not math.isfinite(self.time_offset):
            raise ValueError(f"time offset must be a finite number of s, got {self.time_offset}")
        if self.rotation not in ROTATIONS:
            raise ValueError(f"rotation must be one of {ROTATIONS}, got {self.rotation!r}")
