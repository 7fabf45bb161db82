"""The split policy: which flights train, validate and test, written once.

Whole flights go to one split each (no window crosses splits). ``SPLIT_FRACTIONS`` are the
paper's shares of the windows; ``split_flights`` draws towards them (the simulator's and
``slungload import``'s seeded split), ``split_dataset`` writes the lists of a folder of the
user's own flights (``slungload split``, the same shares as its defaults), and the data study
takes its training share from here.

Nothing heavy is imported at module level: the CLI's help reads ``SPLIT_FRACTIONS``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

SPLIT_FRACTIONS = {"train": 0.58, "val": 0.17, "test": 0.25}  # of windows, the paper's split
WINDOW_STEPS = 75  # M + N = 50 + 25: a flight of T steps gives T - 74 windows (stride 1)


def shares_text() -> str:
    """The shares in per cent as the help writes them: ``58/17/25``."""
    return "/".join(f"{round(100 * f)}" for f in SPLIT_FRACTIONS.values())


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
    from ..fileio import SPLITS

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


def split_dataset(
    folder: str | Path,
    *,
    val: float | Sequence[str] = SPLIT_FRACTIONS["val"],
    test: float | Sequence[str] = SPLIT_FRACTIONS["test"],
    seed: int = 0,
    overwrite: bool = False,
) -> dict[str, list[str]]:
    """Write the split lists of ``folder`` (``slungload split``) and return them (split ->
    flight names).

    Every command needs ``train.txt``, ``val.txt`` and ``test.txt``; this writes them for a
    user's own flights, by flight. val, test: a share of the flights in [0, 1) (rounded, at
    least one flight when the share is positive and there are enough flights), drawn at random
    with ``seed``; or the names of the flights. Every other flight is training. Existing lists
    are kept unless ``overwrite``.
    """
    import numpy as np

    from ..fileio import SPLITS, write_splits
    from .dataset import check_folder

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
