"""Splitting a dataset's flights into train, validation and test, as the paper's split does.

Whole flights go to one split each (no window crosses splits); the shares are of windows.
Used by the simulator's dataset writer and by ``slungload import``; no MuJoCo here.
"""

from __future__ import annotations

import numpy as np

from ..fileio import SPLITS

SPLIT_FRACTIONS = {"train": 0.58, "val": 0.17, "test": 0.25}  # of windows, the paper's split
WINDOW_STEPS = 75  # M + N = 50 + 25: a flight of T steps gives T - 74 windows (stride 1)


def windows_of(steps: int, window: int = WINDOW_STEPS) -> int:
    """Sliding windows (stride 1) of ``window`` steps in a flight of ``steps`` steps."""
    return max(steps - window + 1, 0)


def split_flights(
    names: list[str],
    steps: list[int],
    rng: np.random.Generator,
    families: list[str] | None = None,
) -> dict[str, tuple[str, ...]]:
    """Assign whole flights to train/val/test so each split gets about its share of windows.

    With ``families`` (the maneuver family of each flight), one flight of every family, drawn at
    random, goes to training first: as in the authors' split, where every family has
    repetitions in training, the test measures prediction on kinds of maneuver the network has
    seen rather than extrapolation to new ones. The other flights, in random order and longest
    first within the draw, each go to the split furthest below its target; every split gets
    at least one flight when there are three or more.
    """
    order = list(rng.permutation(len(names)))
    got = {s: 0 for s in SPLITS}
    out: dict[str, list[str]] = {s: [] for s in SPLITS}
    if families is not None:
        if len(families) != len(names):
            raise ValueError(f"{len(families)} families for {len(names)} flights")
        first: dict[str, int] = {}  # family -> its flight drawn first
        for i in order:
            if families[i] not in first and len(names) - len(first) > 2:
                first[families[i]] = i
                out["train"].append(names[i])
                got["train"] += windows_of(steps[i])
        seeded = set(first.values())
        order = [i for i in order if i not in seeded]
    total = sum(windows_of(s) for s in steps) or 1
    order = sorted(order, key=lambda i: -windows_of(steps[i]))
    for rank, i in enumerate(order):
        empty = [s for s in SPLITS if not out[s]]
        if empty and len(order) - rank <= len(empty):
            split = empty[0]
        else:
            split = max(SPLITS, key=lambda s: SPLIT_FRACTIONS[s] * total - got[s])
        out[split].append(names[i])
        got[split] += windows_of(steps[i])
    return {s: tuple(sorted(v)) for s, v in out.items()}
