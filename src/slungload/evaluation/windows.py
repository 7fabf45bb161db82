"""The windows an evaluation measures on: each horizon's windows of one split's flights."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from ..config import WindowConfig
from ..data.windows import Windows, make_windows
from ..fileio import EVERY, HELD_OUT
from ..fileio import SPLITS as PARTS

SPLITS = ("test", "val")
# the splits ``evaluate`` measures on: report on test, choose on val


def split_name(split: str) -> str:
    """What a ``horizon_windows`` split is, in a report: "test split", "held-out flights (val
    and test)", "every flight"."""
    named = {HELD_OUT: "held-out flights (val and test)", EVERY: "every flight"}
    return named.get(split, f"{split} split")


def horizon_windows(
    dataset: Any, *, history: int, horizons: Sequence[int], split: str = "test"
) -> dict[int, Windows]:
    """Windows for each horizon N, cut with stride 1 from the flights of one split.

    dataset: a ``data.Dataset`` (``.splits[split].names``, ``.flights[name].states`` ...,
    ``.params``: the constants of flights that record none of their own).
    Every horizon uses the same flights; a flight shorter than M + N gives no window at N.
    ``split``: one of ``SPLITS``, ``HELD_OUT`` for the val flights then the test flights, or
    ``EVERY`` for every flight (train, val, test: a dataset the model never saw).
    """
    if split not in (*SPLITS, HELD_OUT, EVERY):
        raise ValueError(
            f"evaluate: split must be one of {(*SPLITS, HELD_OUT, EVERY)}, got {split!r}"
        )
    if split == EVERY:
        parts = tuple(part for part in PARTS if part in dataset.splits)
    else:
        parts = ("val", "test") if split == HELD_OUT else (split,)
    names = [name for part in parts for name in dataset.splits[part].names]
    flights = [dataset.flights[name] for name in names if name in dataset.flights]
    if not flights:
        raise ValueError(f"evaluate: the dataset has no {split} flight")
    return {
        n: make_windows(flights, WindowConfig(history=history, horizon=n, stride=1), dataset.params)
        for n in horizons
    }
