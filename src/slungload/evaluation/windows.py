"""The windows an evaluation measures on: each horizon's windows of one split's flights."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from ..config import WindowConfig
from ..data.windows import Windows, make_windows

SPLITS = ("test", "val")
# the splits ``evaluate`` measures on: report on test, choose on val


def horizon_windows(
    dataset: Any, *, history: int, horizons: Sequence[int], split: str = "test"
) -> dict[int, Windows]:
    """Windows for each horizon N, cut with stride 1 from the flights of one split.

    dataset: a ``data.Dataset`` (``.splits[split].names``, ``.flights[name].states`` ...,
    ``.params``: the constants of flights that record none of their own).
    Every horizon uses the same flights; a flight shorter than M + N gives no window at N.
    """
    if split not in SPLITS:
        raise ValueError(f"evaluate: split must be one of {SPLITS}, got {split!r}")
    chosen = dataset.splits[split]
    flights = [dataset.flights[name] for name in chosen.names if name in dataset.flights]
    if not flights:
        raise ValueError(f"evaluate: the dataset has no {split} flight")
    return {
        n: make_windows(flights, WindowConfig(history=history, horizon=n, stride=1), dataset.params)
        for n in horizons
    }
