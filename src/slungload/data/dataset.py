"""A dataset ready for training: its flights (read by ``readers``), windows per split, and the
cache of prepared flights. ``load_dataset`` is the entry; the folder itself (flight files, split
lists, constants) is ``folder``'s; see ``docs/data.md``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import torch

from ..config import VehicleParams, WindowConfig, to_dict
from ..fileio import SPLITS
from .cache import cache_key, default_cache_dir, load_cache, save_cache
from .flight import DatasetError, DataWarning, Flight
from .folder import check_folder, read_splits, resolve_params
from .readers import load_flight
from .windows import Windows, make_windows


@dataclass(frozen=True)
class Dataset:
    """Windows per split ("train", "val", "test") and the flights they were cut from."""

    folder: Path
    params: VehicleParams
    params_source: str  # "vehicle.json" | "override" | "paper defaults"
    window: WindowConfig
    splits: dict[str, Windows]
    flights: dict[str, Flight]
    cache_path: Path | None = None
    from_cache: bool = False
    notes: tuple[str, ...] = field(default=())  # what was skipped or ignored while reading


def load_dataset(
    folder: str | Path,
    *,
    window: WindowConfig = WindowConfig(),  # noqa: B008 (frozen, so a shared default is safe)
    params: VehicleParams | None = None,
    cache_dir: str | Path | None = None,
    use_cache: bool = True,
) -> Dataset:
    """Read, validate and window every flight of a dataset folder, split by flight file.

    ``params`` overrides ``vehicle.json``; without either the paper's defaults apply (with a
    warning). Flights shorter than one window are skipped with a warning. The windows are
    cached in ``cache_dir`` (default ``$SLUNGLOAD_CACHE`` or ``~/.cache/slungload``) under a
    hash of the files' bytes, the window config and the constants.
    """
    folder, paths = check_folder(folder)
    params, source = resolve_params(folder, params)
    names = read_splits(folder)
    files = [paths[n] for s in SPLITS for n in names[s]]
    files += [folder / f"{s}.txt" for s in SPLITS if (folder / f"{s}.txt").is_file()]
    key = cache_key(files, window, params)
    cache_path = (
        Path(cache_dir or default_cache_dir()).expanduser() / f"{folder.name}-{key[:24]}.pt"
    )
    common = {"folder": folder, "params": params, "params_source": source, "window": window}
    chosen = {n: paths[n] for s in SPLITS for n in names[s]}

    if use_cache:
        try:
            payload = load_cache(cache_path, key)
            if payload is not None:
                dataset = _from_payload(payload, common, chosen, cache_path)
                for note in dataset.notes:
                    warnings.warn(note, DataWarning, stacklevel=2)
                return dataset
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            warnings.warn(f"ignoring a bad cache file, rebuilding: {exc}", DataWarning, 2)

    notes: list[str] = []
    flights = _read_flights(folder, chosen, window, params, notes)
    for note in notes:
        warnings.warn(note, DataWarning, stacklevel=2)
    splits = {
        s: make_windows([flights[n] for n in names[s] if n in flights], window, params)
        for s in SPLITS
    }
    dataset = Dataset(**common, splits=splits, flights=flights, notes=tuple(notes))
    if not use_cache:
        return dataset
    try:
        save_cache(cache_path, key, _to_payload(dataset))
    except (OSError, RuntimeError) as exc:  # torch.save reports a full disk as RuntimeError
        warnings.warn(f"cannot write the cache {cache_path}: {exc}", DataWarning, stacklevel=2)
        return dataset
    return replace(dataset, cache_path=cache_path)


def _read_flights(
    folder: Path,
    paths: dict[str, Path],
    window: WindowConfig,
    params: VehicleParams,
    notes: list[str],
) -> dict[str, Flight]:
    """The flights at ``paths`` (name -> file, in split order) long enough for one window."""
    flights: dict[str, Flight] = {}
    longest = 0
    for name, path in paths.items():
        flight = load_flight(path, params, notes)
        longest = max(longest, len(flight))
        if len(flight) < window.length:
            notes.append(
                f"{flight.path}: skipped, {len(flight)} steps is shorter than one window "
                f"(M + N = {window.length})"
            )
            continue
        flights[name] = flight
    if not flights:
        raise DatasetError(
            f"{folder}: no flight left; each needs at least M + N = {window.length} steps "
            f"and the longest has {longest}"
        )
    return flights


_ARRAYS = ("time", "states", "inputs", "aux")


def _to_payload(dataset: Dataset) -> dict:
    """The flights and which split each belongs to. Windows are not stored: they are ~40x the
    flights' size (every step repeated in M + N windows) and re-cut in well under a second."""
    flights = {
        n: {k: torch.from_numpy(getattr(f, k)) for k in _ARRAYS} for n, f in dataset.flights.items()
    }
    for n, f in dataset.flights.items():
        if f.constants is not None:  # the flight's own constants (varied loads)
            flights[n]["constants"] = to_dict(f.constants)
    members = {s: list(dataset.splits[s].names) for s in SPLITS}  # the flights, in order
    return {"flights": flights, "splits": members, "notes": list(dataset.notes)}


def _constants(cached: dict) -> VehicleParams | None:
    constants = cached.get("constants")
    return None if constants is None else VehicleParams(**constants)


def _from_payload(payload: dict, common: dict, paths: dict[str, Path], cache_path: Path) -> Dataset:
    flights = {
        name: Flight(name, paths[name], *(f[k].numpy() for k in _ARRAYS), _constants(f))
        for name, f in payload["flights"].items()
    }
    splits = {
        s: make_windows(
            [flights[str(n)] for n in payload["splits"][s]], common["window"], common["params"]
        )
        for s in SPLITS
    }
    notes = tuple(str(n) for n in payload["notes"])
    return Dataset(
        **common,
        splits=splits,
        flights=flights,
        cache_path=cache_path,
        from_cache=True,
        notes=notes,
    )
