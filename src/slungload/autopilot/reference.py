"""What the bridge flies: a maneuver's offsets (``sim.maneuvers``, numpy only) from where
OFFBOARD started, or that point held, sampled every control period."""

from __future__ import annotations

import math

import numpy as np

from ..sim.maneuvers import Reference, make_maneuver, sample_reference
from ..sim.streams import seed_streams

HOLD_DURATION = 10.0  # s, a hold flown when no duration is given


def flight_reference(
    start: np.ndarray, yaw: float, h: float, maneuver: str | None, seed: int,
    duration: float | None, settle: float = 0.0,
    box: tuple[float, float, float, float, float, float] | None = None,
) -> Reference:  # fmt: skip
    """The reference, one row per control period of the flight (h s apart), from ``start``
    (3,) m, world z up, at heading ``yaw`` rad: ``settle`` s holding ``start``, then
    ``maneuver``'s offsets (drawn as ``sim.flight.simulate_flight`` draws that maneuver for
    ``seed``: its maneuver stream, ``sim.streams``) for T periods, turned with the heading,
    or ``start`` held. T: ``duration`` / h, else the maneuver's length, else
    ``HOLD_DURATION``. Positions are kept inside ``box`` (lowest x, y, z, highest x, y, z, m)
    when given. With heading 0, ``settle`` the simulator's warm-up and ``box`` its arena
    (``sim.maneuvers.ARENA_BOX``) it is the reference ``simulate_flight`` gives its controller
    from ``start``."""
    warm = round(settle / h)
    if maneuver is None:
        steps = warm + round((duration or HOLD_DURATION) / h)
        pos = np.tile(np.asarray(start, float), (steps, 1))
        zero = np.zeros_like(pos)
        return Reference(pos, zero, zero.copy(), np.full(steps, float(yaw)))
    man = make_maneuver(maneuver, seed_streams(seed)[0])
    steps = round(duration / h) if duration is not None else man.steps
    times = (np.arange(warm + steps) - warm) * h  # as sim.flight's: the maneuver starts at 0
    ref = sample_reference(man, times, np.zeros(3), arena=False)
    c, s = math.cos(yaw), math.sin(yaw)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])  # the maneuver's x: heading
    pos = start + ref.position @ turn.T
    if box is not None:
        pos = np.clip(pos, box[:3], box[3:])
    return Reference(pos, ref.velocity @ turn.T, ref.acceleration @ turn.T, ref.yaw + yaw)
