"""A simulated flight's random streams: one per thing it draws, from its seed (numpy only).

Each flight spawns ``len(FLIGHT_STREAMS)`` independent generators from its seed, in this order;
drawing more from one never changes another, so a later kind of draw (the excitation, the
load) left every earlier flight as it was.
"""

from __future__ import annotations

import numpy as np

FLIGHT_STREAMS = ("maneuver", "plant", "wind", "sensors", "excitation", "load")


def seed_streams(seed: int | np.random.SeedSequence) -> tuple[np.random.Generator, ...]:
    """The flight's generators, in ``FLIGHT_STREAMS`` order, from its seed."""
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    return tuple(np.random.default_rng(s) for s in ss.spawn(len(FLIGHT_STREAMS)))
