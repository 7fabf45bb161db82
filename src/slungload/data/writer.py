"""Writing a dataset folder, all or nothing: flights, split lists and ``vehicle.json``.

The one writer of datasets: the simulator (``sim/dataset.py``: flights at the top of the
folder, written by its worker processes) and ``slungload import`` (``importing.py``: flights
under ``data/``, the authors' release layout) both write through ``DatasetWriter``::

    with DatasetWriter(out, overwrite=False, subfolder="data") as writer:
        writer.write_flight("flight_00", arrays)   # or write_npz(writer.flight_path(name), ...)
        writer.finish(splits, params, {"import": {...}})

Everything goes into a temporary folder beside ``out`` (``.NAME.XXXXXXXX.tmp``, created with
the permissions of a plain ``mkdir``), renamed to ``out`` by ``finish``; leaving the ``with``
block without ``finish`` (an error, an interrupt) removes it, so a failure leaves nothing
half-written and an existing ``out`` untouched. A non-empty ``out`` is refused unless
``overwrite``, before any work is done.
"""

from __future__ import annotations

import secrets
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..config import VehicleParams, to_dict
from ..fileio import write_json, write_npz, write_splits
from ..vehicle_file import VEHICLE_FILE


class DatasetWriter:
    """A dataset folder being written (see the module's docstring).

    ``subfolder``: where the flights go inside the folder, "" (the top, the simulator's layout)
    or ``"data"`` (the authors' release layout). ``folder`` is the temporary folder while the
    ``with`` block runs; ``flight_path(name)`` is where a flight is written, from this process
    or another one.
    """

    def __init__(self, out: str | Path, *, overwrite: bool = False, subfolder: str = "") -> None:
        self.out = out = Path(out).expanduser()
        self.subfolder = subfolder
        if not overwrite and out.exists() and (not out.is_dir() or any(out.iterdir())):
            raise FileExistsError(
                f"{out}: exists and is not empty (--overwrite, or overwrite=True, replaces it)"
            )
        self._folder: Path | None = None
        self._done = False

    @property
    def folder(self) -> Path:
        """The temporary folder that becomes ``out`` (only inside the ``with`` block)."""
        if self._folder is None:
            raise RuntimeError("DatasetWriter: use it in a with block")
        return self._folder

    def __enter__(self) -> DatasetWriter:
        self.out.parent.mkdir(parents=True, exist_ok=True)
        self._folder = _new_folder(self.out)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._folder is not None and not self._done and self._folder.exists():
            shutil.rmtree(self._folder)

    def flight_path(self, name: str) -> Path:
        """Where the flight ``name`` is written (``.npz``, the published schema)."""
        return self.folder / self.subfolder / f"{name}.npz"

    def write_flight(self, name: str, arrays: Mapping[str, np.ndarray]) -> Path:
        path = self.flight_path(name)
        write_npz(path, arrays)
        return path

    def finish(
        self,
        splits: Mapping[str, Sequence[str]],
        params: VehicleParams,
        about: Mapping[str, Any],
    ) -> Path:
        """Write the split lists and ``vehicle.json`` (``params`` under "vehicle", then
        ``about``: what made the data, with the package version, ``_version.__version__``),
        and put the folder in place of
        ``out``."""
        write_splits(self.folder, {s: list(v) for s, v in splits.items()})
        write_json(self.folder / VEHICLE_FILE, {"vehicle": to_dict(params), **about})
        if self.out.is_dir() and not self.out.is_symlink():
            shutil.rmtree(self.out)
        elif self.out.exists() or self.out.is_symlink():
            self.out.unlink()
        self.folder.rename(self.out)
        self._done = True
        return self.out


def _new_folder(out: Path) -> Path:
    """A new, empty folder beside ``out``, with the mode ``mkdir`` gives (0o777 less the
    umask; ``tempfile.mkdtemp`` would make it private)."""
    for _ in range(100):
        path = out.parent / f".{out.name}.{secrets.token_hex(4)}.tmp"
        try:
            path.mkdir()
        except FileExistsError:
            continue
        return path
    raise FileExistsError(f"{out.parent}: no free temporary name for {out.name}")
