"""The split policy: which flights train, validate and test, written once.

Whole recordings go to one split each: a flight, or every piece of one log that a gap split
into several flights (no window crosses splits, and no test window shares a recording with a
training window). ``SPLIT_FRACTIONS`` are the paper's shares of the windows; ``split_flights``
draws towards them (the simulator's and ``slungload import``'s seeded split), ``split_dataset``
writes the lists of a folder of the user's own flights (``slungload split``, the same shares as
its defaults), and the data study takes its training share from here.

With one or two recordings there is nothing to draw: ``time_blocks`` cuts each recording in
time instead, into a training, a validation and a test block in that order, the paper's
shares of its steps, with ``gap`` steps left out between blocks (at least M + N, so no window
of one block would have overlapped the next); ``split_blocks`` (``slungload split --blocks``)
and ``slungload import --split blocks`` use it.

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
    recordings: list[str] | None = None,
) -> dict[str, tuple[str, ...]]:
    """Assign whole flights to train/val/test so each split gets about its share of windows.

    ``recordings`` (the recording of each flight, e.g. the log a piece came from): the
    flights of one recording go to one split together, drawn as one unit with their windows
    summed. With ``families`` (the maneuver family of each flight), one unit of every family,
    drawn at random, goes to training first: as in the authors' split, where every family has
    repetitions in training, the test measures prediction on kinds of maneuver the network has
    seen rather than extrapolation to new ones. The other units, in random order and largest
    first within the draw, each go to the split furthest below its target; every split gets
    at least one unit when there are three or more.
    """
    if families is not None and len(families) != len(names):
        raise ValueError(f"{len(families)} families for {len(names)} flights")
    units = names if recordings is None else list(dict.fromkeys(recordings))
    members = {u: [n] for u, n in zip(units, names, strict=True)} if recordings is None else {
        u: [n for n, r in zip(names, recordings, strict=True) if r == u] for u in units
    }  # fmt: skip
    index = {n: i for i, n in enumerate(names)}
    windows = [sum(windows_of(steps[index[n]]) for n in members[u]) for u in units]
    unit_families = None
    if families is not None:
        unit_families = [families[index[members[u][0]]] for u in units]
    drawn = _draw(units, windows, rng, unit_families)
    return {s: tuple(sorted(n for u in v for n in members[u])) for s, v in drawn.items()}


def _draw(
    units: list[str], windows: list[int], rng: np.random.Generator, families: list[str] | None
) -> dict[str, list[str]]:
    from ..fileio import SPLITS

    order = list(rng.permutation(len(units)))
    got = {s: 0 for s in SPLITS}
    out: dict[str, list[str]] = {s: [] for s in SPLITS}
    if families is not None:
        first: dict[str, int] = {}  # family -> its unit drawn first
        for i in order:
            if families[i] not in first and len(units) - len(first) > 2:
                first[families[i]] = i
                out["train"].append(units[i])
                got["train"] += windows[i]
        seeded = set(first.values())
        order = [i for i in order if i not in seeded]
    total = sum(windows) or 1
    order = sorted(order, key=lambda i: -windows[i])
    for rank, i in enumerate(order):
        empty = [s for s in SPLITS if not out[s]]
        if empty and len(order) - rank <= len(empty):
            split = empty[0]
        else:
            split = max(SPLITS, key=lambda s: SPLIT_FRACTIONS[s] * total - got[s])
        out[split].append(units[i])
        got[split] += windows[i]
    return out


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
    user's own flights, by recording (``recordings_of``: the pieces of one imported log stay
    together). val, test: a share of the recordings in [0, 1) (rounded, at least one when the
    share is positive and there are enough), drawn at random with ``seed``; or the names of
    the flights (every piece of their recordings). Every other flight is training. Existing
    lists are kept unless ``overwrite``. Too few recordings for a split is an error that
    names the time-block split (``split_blocks``).
    """
    import numpy as np

    from ..fileio import SPLITS, write_splits
    from .folder import check_folder

    folder, files = check_folder(folder)
    names = sorted(files)
    existing = [s for s in SPLITS if (folder / f"{s}.txt").is_file()]
    if existing and not overwrite:
        raise FileExistsError(
            f"{folder}: already has split lists ({', '.join(f'{s}.txt' for s in existing)}); "
            "--overwrite (overwrite=True) replaces them"
        )
    owner = recordings_of(folder, names)
    pieces = {r: [n for n in names if owner[n] == r] for r in dict.fromkeys(owner.values())}
    rng = np.random.default_rng(seed)
    left = list(pieces)
    chosen: dict[str, list[str]] = {}
    for split, spec in (("test", test), ("val", val)):
        if not isinstance(spec, (str, float, int)) and isinstance(spec, Sequence):
            spec = _whole_recordings(split, spec, owner, pieces)
        chosen[split] = _take(split, spec, left, len(pieces), rng)
        left = [r for r in left if r not in chosen[split]]
    if not left:
        raise ValueError(f"{folder}: no recording left for training ({len(pieces)} recordings)")
    splits = {
        "train": [n for r in left for n in pieces[r]],
        **{s: sorted(n for r in chosen[s] for n in pieces[r]) for s in ("val", "test")},
    }
    write_splits(folder, splits)
    return splits


def recordings_of(folder: Path, names: list[str]) -> dict[str, str]:
    """Flight -> its recording: the block split's or the import's record in ``vehicle.json``
    (the log a piece came from), else the flight itself."""
    import json

    from ..vehicle_file import VEHICLE_FILE

    try:
        data = json.loads((folder / VEHICLE_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        data = {}
    blocks = _get(data, "blocks", "flights")
    imported = _get(data, "import", "flights")
    out = {}
    for n in names:
        if isinstance(blocks.get(n), dict) and "recording" in blocks[n]:
            out[n] = str(blocks[n]["recording"])
        elif isinstance(imported.get(n), dict) and "log" in imported[n]:
            out[n] = str(imported[n]["log"])
        else:
            out[n] = n
    return out


def _get(data: object, *keys: str) -> dict:
    for key in keys:
        data = data.get(key, {}) if isinstance(data, dict) else {}
    return data if isinstance(data, dict) else {}


def _whole_recordings(
    split: str, flights: Sequence[str], owner: dict[str, str], pieces: dict[str, list[str]]
) -> list[str]:
    """The recordings of the flights named for ``split``; naming only some pieces of a
    recording is an error that names the others."""
    unknown = [n for n in flights if n not in owner]
    if unknown:
        raise ValueError(f"--{split}: flights not in the folder: {unknown}")
    recordings = list(dict.fromkeys(owner[n] for n in flights))
    for r in recordings:
        missing = [n for n in pieces[r] if n not in flights]
        if missing:
            raise ValueError(
                f"--{split}: {', '.join(n for n in pieces[r] if n in flights)} is one piece of "
                f"a recording ({r}) whose other pieces {missing} would land in another split; "
                "name them too, or cut the recording in time (slungload split --blocks)"
            )
    return recordings


def _take(
    split: str, spec: float | Sequence[str], left: list[str], total: int, rng: np.random.Generator
) -> list[str]:
    """The recordings of one split: named ones (checked), or a share drawn from ``left``."""
    if isinstance(spec, str):
        raise TypeError(f"{split}: pass a share or a list of flight names, not one string")
    if isinstance(spec, Sequence):
        taken = [n for n in spec if n not in left]
        if taken:
            raise ValueError(f"--{split}: flights already taken by another split: {taken}")
        return list(spec)
    if not 0.0 <= spec < 1.0:
        raise ValueError(f"--{split}: a share must be in [0, 1), got {spec}")
    count = max(1, round(spec * total)) if spec > 0 else 0
    if count >= len(left):
        raise ValueError(
            f"--{split}: {count} of {total} recording(s) would leave none for training; with "
            "one or two recordings, cut each in time: slungload split --blocks (train, val "
            "and test blocks separated by M + N steps)"
        )
    picks = rng.choice(len(left), size=count, replace=False)
    return [left[i] for i in sorted(picks)]


# --- time blocks within a recording ------------------------------------------------------------


def time_blocks(lengths: list[int], gap: int = WINDOW_STEPS) -> list[tuple[int, int, int, str]]:
    """Cut one recording (its pieces' step counts, in time order) into a training, a
    validation and a test block, in that order, with the paper's shares of its steps and
    ``gap`` steps left out between blocks (at least M + N, so no window of one block would
    have overlapped the next). Returns (piece, first step, stop, split) segments; a block may
    span pieces. A recording too short for three blocks of at least ``gap`` steps is an
    error."""
    total = sum(lengths)
    usable = total - 2 * gap
    sizes = [int(usable * SPLIT_FRACTIONS[s]) for s in ("train", "val")]
    sizes.append(usable - sum(sizes))
    if gap < 1 or min(sizes) < gap:
        raise ValueError(
            f"a recording of {total} steps is too short for a time-block split: three blocks of "
            f"at least {gap} steps (M + N) with {gap} steps between them need "
            f"{int(5 * gap / min(SPLIT_FRACTIONS.values())) + 1} or more"
        )
    ranges, cursor = [], 0
    for size, split in zip(sizes, ("train", "val", "test"), strict=True):
        ranges.append((cursor, cursor + size, split))
        cursor += size + gap
    out, offset = [], 0
    for piece, n in enumerate(lengths):
        for a, b, split in ranges:
            lo, hi = max(a, offset), min(b, offset + n)
            if hi - lo >= 2:  # a flight needs two samples
                out.append((piece, lo - offset, hi - offset, split))
        offset += n
    return out


def split_blocks(folder: str | Path, *, gap: int = WINDOW_STEPS) -> dict[str, list[str]]:
    """``slungload split --blocks``: rewrite ``folder`` with each recording cut in time
    (``time_blocks``): flight ``NAME`` becomes ``NAME_train``, ``NAME_val``, ``NAME_test``
    (the parts of it in each block, time restarting at 0), listed in their splits;
    ``vehicle.json`` keeps its content and records the cut under ``"blocks"``. All or
    nothing (``writer.DatasetWriter``). Returns the split lists."""
    from ..fileio import read_npz
    from ..vehicle_file import VEHICLE_FILE, load_vehicle
    from .folder import check_folder
    from .writer import DatasetWriter

    folder, files = check_folder(folder)
    names = sorted(files)
    owner = recordings_of(folder, names)
    meta = _read_json(folder / VEHICLE_FILE)
    arrays = {n: read_npz(files[n]) for n in names}
    splits: dict[str, list[str]] = {"train": [], "val": [], "test": []}
    record: dict[str, dict] = {}
    subfolder = "" if files[names[0]].parent == folder else files[names[0]].parent.name
    known = {*(p.name for p in files.values()), VEHICLE_FILE, *(f"{s}.txt" for s in splits)}
    other = sorted(
        str(p.relative_to(folder))
        for p in [*folder.iterdir(), *((folder / subfolder).iterdir() if subfolder else [])]
        if p.name not in known and p.name != subfolder
    )
    if other:
        raise ValueError(
            f"{folder}: the block split rewrites the folder and would lose {other}; move them "
            "out first"
        )
    with DatasetWriter(folder, overwrite=True, subfolder=subfolder) as writer:
        for recording in dict.fromkeys(owner.values()):
            pieces = sorted(n for n in names if owner[n] == recording)
            lengths = [len(arrays[n]["time"]) for n in pieces]
            for piece, a, b, split in time_blocks(lengths, gap):
                name = f"{pieces[piece]}_{split}"
                cut = {k: v[a:b] for k, v in arrays[pieces[piece]].items()}
                cut["time"] = cut["time"] - cut["time"][0]
                writer.write_flight(name, cut)
                splits[split].append(name)
                record[name] = {"from": pieces[piece], "start": a, "steps": b - a,
                                "recording": recording}  # fmt: skip
        meta.pop("vehicle", None)
        meta["blocks"] = {"gap": gap, "flights": record}
        writer.finish(splits, load_vehicle(folder) or _defaults(), meta)
    return splits


def _read_json(path: Path) -> dict:
    import json

    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _defaults():
    from ..config import VehicleParams

    return VehicleParams()
