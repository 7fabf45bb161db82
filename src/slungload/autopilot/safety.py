"""The bridge's safety checks, before every MPC step: what makes it hover and then hand the
vehicle back to the autopilot (``bridge.Bridge``). Numpy only.

A check names the first fault it finds (``EVENTS``), in this order: a vehicle state or a load
position older than its limit, a non-finite value in the state, the vehicle outside the
geofence (a cylinder about where OFFBOARD started), or tilted beyond the attitude limit. The
bridge adds the MPC's own hover fallback (``MPCStats.hover_steps``) and a non-finite command
(which the MPC cannot return; checked at the wire all the same).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from ..control.mppi import tilt_of
from ..layout import POS, QUAT
from .config import BridgeConfig

EVENTS = ("stale state", "stale load", "non-finite state", "outside geofence",
          "attitude limit", "mpc fallback", "non-finite command")  # fmt: skip


def check_state(
    state: np.ndarray, state_age: float, load_age: float, origin: np.ndarray, cfg: BridgeConfig
) -> str | None:
    """The first fault (an entry of ``EVENTS``) of the state (13,) in the package's layout,
    measured ``state_age`` s ago with the load ``load_age`` s ago, about ``origin`` (3,) m
    (where OFFBOARD started); None when it is safe to fly the MPC on it."""
    if not state_age <= cfg.max_state_age:  # a NaN age is stale too
        return "stale state"
    if not load_age <= cfg.max_load_age:
        return "stale load"
    if not np.isfinite(state).all():
        return "non-finite state"
    offset = state[POS] - origin
    if math.hypot(offset[0], offset[1]) > cfg.fence_radius or abs(offset[2]) > cfg.fence_height:
        return "outside geofence"
    if tilt_of(state[QUAT]) > cfg.max_tilt:
        return "attitude limit"
    return None


@dataclass
class SafetyLog:
    """Every safety event, counted by reason and kept with its time (s, the bridge's clock)."""

    counts: Counter = field(default_factory=Counter)
    events: list[tuple[float, str]] = field(default_factory=list)

    def add(self, t: float, reason: str) -> None:
        self.counts[reason] += 1
        self.events.append((t, reason))
