"""A dataset folder: its flights (read by ``readers``), the split lists ``train.txt`` /
``val.txt`` / ``test.txt``, the vehicle constants (``vehicle.json``), windows per split, and the
cache of prepared flights. ``load_dataset`` is the entry; see ``docs/data.md``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import torch

from ..config import VehicleParams, WindowConfig, to_dict
from ..fileio import SPLITS
from ..vehicle_file import load_vehicle
from .cache import cache_key, default_cache_dir, load_cache, save_cache
from .flight import DatasetError, DataWarning, Flight
from .readers import flight_files, flight_suffixes, load_flight
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


def resolve_params(folder: Path, params: VehicleParams | None) -> tuple[VehicleParams, str]:
    """Constants to use and where they come from: explicit > vehicle.json > paper defaults."""
    if params is not None:
        return params, "override"
    found = load_vehicle(folder)
    if found is not None:
        return found, "vehicle.json"
    defaults = VehicleParams()
    warnings.warn(
        f"{folder}: no vehicle.json, using the paper's default constants {defaults}",
        DataWarning,
        stacklevel=3,
    )
    return defaults, "paper defaults"


def check_folder(folder: str | Path) -> tuple[Path, dict[str, Path]]:
    """A dataset folder and its flight files (name -> path); errors name what is wrong."""
    folder = Path(folder).expanduser()
    kinds = ", ".join(f"*{s}" for s in flight_suffixes())
    if folder.exists() and not folder.is_dir():
        raise NotADirectoryError(
            f"dataset folder {folder} is not a folder (expected a folder of flights: {kinds})"
        )
    if not folder.is_dir():
        raise FileNotFoundError(f"dataset folder {folder} does not exist")
    files = flight_files(folder)
    if not files:
        raise DatasetError(
            f"dataset folder {folder} holds no flight files ({kinds}), neither at the top nor "
            "under data/"
        )
    return folder, files


def read_splits(folder: str | Path) -> dict[str, list[str]]:
    """Flight names per split from train.txt / val.txt / test.txt (with or without ``.npz``).

    One name a line; blank lines and lines starting with '#' are skipped. Raises
    ``DatasetError`` for no split files, names missing on disk or listed twice; a missing list
    is an empty split and flights in no list are ignored, each with a ``DataWarning``.
    """
    folder = Path(folder)
    present = [s for s in SPLITS if (folder / f"{s}.txt").is_file()]
    suffixes = tuple(flight_suffixes())
    if not present:
        raise DatasetError(
            f"{folder}: no split files. Write train.txt, val.txt and test.txt beside the flights, "
            "one flight name a line, e.g. slungload.fileio.write_splits(folder, "
            "{'train': [...], 'val': [...], 'test': [...]})"
        )
    on_disk = set(flight_files(folder))
    names: dict[str, list[str]] = {s: [] for s in SPLITS}
    owner: dict[str, str] = {}
    for split in SPLITS:
        list_path = folder / f"{split}.txt"
        if split not in present:
            warnings.warn(f"{list_path} is missing: split '{split}' is empty", DataWarning, 2)
            continue
        for line in _read_list(list_path):
            name = line.strip()
            suffix = Path(name).suffix
            if suffix.lower() in suffixes:  # the authors' lists name files, ours flights
                name = name[: -len(suffix)]
            if not name or name.startswith("#"):
                continue
            if name in owner:
                where = (
                    "listed twice" if owner[name] == split else f"also listed in {owner[name]}.txt"
                )
                raise DatasetError(f"{list_path}: flight '{name}' is {where}")
            owner[name] = split
            names[split].append(name)
        absent = [n for n in names[split] if n not in on_disk]
        if absent:
            raise DatasetError(f"{list_path}: flights not found in {folder}: {absent}")
    unlisted = sorted(on_disk - set(owner))
    if unlisted:
        warnings.warn(f"{folder}: flights in no split list are ignored: {unlisted}", DataWarning, 2)
    return names


def _read_list(path: Path) -> list[str]:
    """Lines of a split list; a file that is not UTF-8 text is a ``DatasetError``."""
    try:
        return path.read_text(encoding="utf-8").splitlines()
    except UnicodeDecodeError as exc:
        raise DatasetError(
            f"{path}: not a text file ({exc.reason} at byte {exc.start}); expected one flight "
            "name a line"
        ) from None


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
