"""Flight readers by source: one module per format, each turning one file into a validated
``Flight`` (``flight.py`` holds the checks every reader shares).

``READERS`` maps a format name to its reader and the file suffixes it claims; a dataset folder's
flights are its files with a claimed suffix (``flight_files``), each read by the reader of its
suffix, or by the reader named by an explicit ``format``. The flights lie at the top of the
folder or under ``data/`` (the authors' release layout). A new source is a module here with a
``read(path, params, notes) -> Flight`` function (numpy; the flight's load state is left to
``load_flight``, which estimates it for every format alike) and one entry below.

``LOG_READERS`` does the same for flight *logs* (``slungload import``: ROS bags, PX4 ULog,
CSV, MAVLink .tlog), which are recordings to convert rather than dataset files: a format
name -> the suffixes it claims, its section of a mapping file and its reader, named as
``module:function`` and imported on first use (so rosbags, pyulog and pymavlink load only
when such a log is read). A new log
format is a module here with ``read(path, mapping, *, progress, roles) -> logs.RawLog`` (``roles``:
the streams wanted, ``logs.ROLES``, None for all; a second log is read for a few) and one entry.
"""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable, Collection
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ...config import VehicleParams
from ..flight import DatasetError, DataWarning, Flight, FlightFormatError
from . import npz

if TYPE_CHECKING:
    from .logs import RawLog


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
    path: Path,
    params: VehicleParams,
    notes: list[str],
    *,
    format: str | None = None,
    load_state: bool = True,
) -> Flight:
    """Read and validate one flight; what was ignored is appended to ``notes``. With
    ``load_state`` its load state is estimated with ``params`` (``Flight.with_load_state``,
    torch); without, ``aux`` is None and nothing imports torch (``inspect``)."""
    flight = reader_for(path, format).read(path, params, notes)
    return flight.with_load_state(params) if load_state else flight


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


# --- flight logs (slungload import) ------------------------------------------------------------


@dataclass(frozen=True)
class LogReader:
    """One log format: its suffixes, its section of a mapping file and its reader."""

    suffixes: tuple[str, ...]  # lower case, with the dot
    section: str  # the mapping file's section that holds this format's settings
    function: str  # "module:function" here: (path, mapping, *, progress, roles) -> RawLog
    folder_marker: str | None = None  # a folder holding this file is one log (rosbag2)
    presets: bool = False  # takes the bags' default topics (--preset)

    def load(self) -> Callable[..., RawLog]:
        """The reader function, imported now (its module may load a log library)."""
        module, name = self.function.split(":")
        return getattr(importlib.import_module(f"{__name__}.{module}"), name)

    def read(
        self,
        path: Path,
        mapping: dict[str, Any] | None = None,
        *,
        preset: str | None = None,
        progress: bool = False,
        roles: Collection[str] | None = None,
    ) -> RawLog:
        """One log's streams. ``mapping`` holds this format's settings, or sections ("ros",
        "ulog", "csv") of every format's; ``preset`` is ignored by formats without presets;
        ``roles``: the streams to read (``logs.ROLES``; None: every one)."""
        mapping = dict(mapping or {})
        if any(isinstance(mapping.get(r.section), dict) for r in LOG_READERS.values()):
            mapping = dict(mapping.get(self.section, {}))
        if preset is not None and self.presets:
            mapping["preset"] = preset
        return self.load()(path, mapping, progress=progress, roles=roles)


LOG_READERS: dict[str, LogReader] = {
    "ros1": LogReader((".bag",), "ros", "rosbag:read_bag", presets=True),
    "ros2": LogReader((".mcap", ".db3"), "ros", "rosbag:read_bag", "metadata.yaml", True),
    "ulog": LogReader((".ulg",), "ulog", "ulog:read_ulog"),
    "csv": LogReader((".csv",), "csv", "csv_log:read_csv"),
    "tlog": LogReader((".tlog",), "tlog", "tlog:read_tlog"),  # MAVLink, as `fly` writes it
}


def log_suffixes() -> list[str]:
    """Every suffix a registered log reader claims."""
    return [s for reader in LOG_READERS.values() for s in reader.suffixes]


def log_format(path: Path) -> str | None:
    """The log format of ``path`` (a file by its suffix, a folder by its marker file), or
    None."""
    for name, reader in LOG_READERS.items():
        if path.is_dir():
            if reader.folder_marker and (path / reader.folder_marker).is_file():
                return name
        elif path.suffix.lower() in reader.suffixes:
            return name
    return None
