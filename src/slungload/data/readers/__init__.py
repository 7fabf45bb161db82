"""Flight readers by source: one module per format, each turning one file into a validated
``Flight`` (``flight.py`` holds the checks every reader shares).

``READERS`` maps a format name to its reader and the file suffixes it claims; a dataset folder's
flights are its files with a claimed suffix (``flight_files``), each read by the reader of its
suffix, or by the reader named by an explicit ``format``. The flights lie at the top of the
folder or under ``data/`` (the authors' release layout). A new source is a module here with a
``read(path, params, notes) -> Flight`` function and one entry below.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ...config import VehicleParams
from ..flight import DatasetError, DataWarning, Flight, FlightFormatError
from . import npz


@dataclass(frozen=True)
class Reader:
    """One source format: the suffixes its files carry and the function that reads one."""

    suffixes: tuple[str, ...]  # lower case, with the dot
    read: Callable[[Path, VehicleParams, list[str]], Flight]  # notes collects what was ignored


READERS: dict[str, Reader] = {
    "npz": Reader((".npz",), npz.read),  # the published schema (fileio.FLIGHT_KEYS)
}


def reader_for(path: Path, format: str | None = None) -> Reader:
    """The reader named ``format``, else the one claiming ``path``'s suffix."""
    if format is not None:
        if format not in READERS:
            raise ValueError(f"unknown flight format {format!r}; known: {sorted(READERS)}")
        return READERS[format]
    suffix = path.suffix.lower()
    for reader in READERS.values():
        if suffix in reader.suffixes:
            return reader
    raise FlightFormatError(f"{path}: no reader for '{suffix}' files; known: {flight_suffixes()}")


def flight_suffixes() -> list[str]:
    """Every suffix a registered reader claims."""
    return [s for reader in READERS.values() for s in reader.suffixes]


DATA_SUBFOLDER = "data"  # the authors' release: DATASET/data/NAME.npz, lists in DATASET/


def flight_files(folder: Path) -> dict[str, Path]:
    """Flight name (file stem) -> file, for every file with a claimed suffix, sorted by name.

    The flights are at the top of ``folder`` (the simulator's layout) or under
    ``folder/data/`` (the authors' release layout, with the split lists beside ``data/``);
    flights in both places are a ``DatasetError`` (which ones would be meant is unclear).
    """
    top = _claimed(folder)
    sub = folder / DATA_SUBFOLDER
    below = _claimed(sub) if sub.is_dir() else {}
    if top and below:
        raise DatasetError(
            f"{folder}: flight files both at the top ({len(top)}) and under {DATA_SUBFOLDER}/ "
            f"({len(below)}); keep one place (the authors' layout: DATASET/{DATA_SUBFOLDER}/*.npz "
            "with train.txt, val.txt, test.txt beside data/)"
        )
    return top or below


def _claimed(folder: Path) -> dict[str, Path]:
    suffixes = set(flight_suffixes())
    files = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in suffixes]
    return {p.stem: p for p in sorted(files)}


def load_flight(
    path: Path, params: VehicleParams, notes: list[str], *, format: str | None = None
) -> Flight:
    """Read and validate one flight; what was ignored is appended to ``notes``."""
    return reader_for(path, format).read(path, params, notes)


def read_flight(
    path: str | Path, params: VehicleParams | None = None, *, format: str | None = None
) -> Flight:
    """Read and validate one flight file (by its suffix, or ``format``); raises
    ``FlightFormatError`` naming the file.

    ``params.dt`` is the expected time step; ``params`` also feeds the load-state estimate.
    What is ignored (e.g. unknown keys) is reported as a ``DataWarning``.
    """
    notes: list[str] = []
    flight = load_flight(Path(path), params or VehicleParams(), notes, format=format)
    for note in notes:
        warnings.warn(note, DataWarning, stacklevel=2)
    return flight
