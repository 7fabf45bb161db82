"""A dataset folder without reading its flights: its flight files (``check_folder``), the split
lists ``train.txt`` / ``val.txt`` / ``test.txt`` (``read_splits``) and the vehicle constants
(``resolve_params``: given, ``vehicle.json`` or the paper's defaults). Light (no torch), so the
commands that only look at a folder (``inspect``, ``split``) start at once; ``dataset`` reads
and windows the flights.
"""

from __future__ import annotations

import warnings
from pathlib import Path

from ..config import VehicleParams
from ..fileio import SPLITS
from ..vehicle_file import load_vehicle
from .flight import DatasetError, DataWarning
from .readers import flight_files, flight_suffixes


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
