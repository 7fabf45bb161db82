"""Split lists for a folder of flights: ``slungload split``.

Every command needs ``train.txt``, ``val.txt`` and ``test.txt``; this writes them for a user's
own flights, by flight (never by window, so no flight is in two splits): either the named
flights go to validation and test and the rest to training, or a seeded random draw takes the
given shares of the flights.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..fileio import SPLITS, write_splits
from .dataset import check_folder


def split_dataset(
    folder: str | Path,
    *,
    val: float | Sequence[str] = 0.17,
    test: float | Sequence[str] = 0.25,
    seed: int = 0,
    overwrite: bool = False,
) -> dict[str, list[str]]:
    """Write the split lists of ``folder`` and return them (split -> flight names).

    val, test: a share of the flights in [0, 1) (rounded, at least one flight when the share
    is positive and there are enough flights), drawn at random with ``seed``; or the names of
    the flights. Every other flight is training. Existing lists are kept unless ``overwrite``.
    """
    folder, files = check_folder(folder)
    names = sorted(files)
    existing = [s for s in SPLITS if (folder / f"{s}.txt").is_file()]
    if existing and not overwrite:
        raise FileExistsError(
            f"{folder}: already has split lists ({', '.join(f'{s}.txt' for s in existing)}); "
            "--overwrite (overwrite=True) replaces them"
        )
    rng = np.random.default_rng(seed)
    left = list(names)
    chosen: dict[str, list[str]] = {}
    for split, spec in (("test", test), ("val", val)):
        chosen[split] = _take(split, spec, left, len(names), rng)
        left = [n for n in left if n not in chosen[split]]
    if not left:
        raise ValueError(f"{folder}: no flight left for training ({len(names)} flights)")
    splits = {"train": left, "val": sorted(chosen["val"]), "test": sorted(chosen["test"])}
    write_splits(folder, splits)
    return splits


def _take(
    split: str, spec: float | Sequence[str], left: list[str], total: int, rng: np.random.Generator
) -> list[str]:
    """The flights of one split: named ones (checked), or a share drawn from ``left``."""
    if isinstance(spec, str):
        raise TypeError(f"{split}: pass a share or a list of flight names, not one string")
    if isinstance(spec, Sequence):
        unknown = [n for n in spec if n not in left]
        if unknown:
            raise ValueError(f"--{split}: flights not in the folder or already taken: {unknown}")
        return list(spec)
    if not 0.0 <= spec < 1.0:
        raise ValueError(f"--{split}: a share must be in [0, 1), got {spec}")
    count = max(1, round(spec * total)) if spec > 0 else 0
    if count >= len(left):
        raise ValueError(f"--{split}: {count} of {total} flights would leave none for training")
    picks = rng.choice(len(left), size=count, replace=False)
    return [left[i] for i in sorted(picks)]
