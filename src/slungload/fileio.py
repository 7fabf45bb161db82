"""Files on disk: the published flight schema, safe reading, atomic and reproducible writing.

Every output of the package goes through ``atomic_path`` so that a crash never leaves a
truncated file that a later run would trust.

Flight files (one ``.npz`` per flight, the authors' published format)::

    time      (T,)    s
    p         (T, 3)  vehicle position, m, world z up
    v         (T, 3)  vehicle velocity, m/s
    attitude  (T, 4)  quaternion x-y-z-w, body -> world
    p_load    (T, 3)  load position, m
    w_ref     (T, 3)  commanded body rates, rad/s
    T_ref     (T, 1)  commanded total thrust, N

Optional: ``t_sampling``; the flight's own constants where they differ from flight to flight
(simulated varied loads), 0-d float arrays named as the ``config.VehicleParams`` fields:
``mass_quad`` (kg), ``mass_load`` (kg), ``cable_length`` (m, effective: vehicle centre of mass
to load centre); ignored: the MATLAB conversion keys ``__header__``, ``__version__``,
``__globals__``. The authors' loader reads only the keys above, so it ignores the optional ones.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import tempfile
import zipfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

FLIGHT_KEYS: dict[str, tuple[int, ...] | None] = {
    "time": (),
    "p": (3,),
    "v": (3,),
    "attitude": (4,),
    "p_load": (3,),
    "w_ref": (3,),
    "T_ref": (1,),
}  # key -> trailing shape after the time axis
CONSTANT_KEYS = ("mass_quad", "mass_load", "cable_length")  # optional per-flight constants
OPTIONAL_KEYS = ("t_sampling", *CONSTANT_KEYS)
IGNORED_KEYS = ("__header__", "__version__", "__globals__")
SPLITS = ("train", "val", "test")
HELD_OUT = "held-out"  # val and test together: every flight training did not fit
EVERY = "all"  # every flight: a dataset (another vehicle, another load) training never saw

# A fixed timestamp for zip members, so the same arrays give the same bytes.
_ZIP_DATE = (2024, 1, 1, 0, 0, 0)


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` only on success."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        # The bytes reach the disk before the name does: after a power cut the file is either
        # the old one or the whole new one.
        with open(tmp_path, "rb+") as f:
            os.fsync(f.fileno())
        # mkstemp makes the file private; give it the mode a plain open() would have.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp_path, 0o666 & ~umask)
        os.replace(tmp_path, path)
    finally:
        tmp_path.unlink(missing_ok=True)


def write_text(path: str | Path, text: str) -> None:
    """Write a text file atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def write_json(path: str | Path, data: Any) -> None:
    """Write JSON atomically, indented and key-sorted (stable bytes)."""
    write_text(path, json.dumps(data, indent=2, sort_keys=True) + "\n")


def read_json(path: str | Path) -> Any:
    """The JSON content of ``path`` (``write_json``'s inverse)."""
    return json.loads(Path(path).read_text())


def write_npz(path: str | Path, arrays: Mapping[str, np.ndarray]) -> None:
    """Write an uncompressed ``.npz`` atomically with fixed member timestamps.

    Same arrays -> same bytes (``np.savez`` stamps members with the current time).
    """
    with atomic_path(path) as tmp:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED) as zf:
            for name in sorted(arrays):
                buf = io.BytesIO()
                np.lib.format.write_array(buf, np.asarray(arrays[name]), allow_pickle=False)
                info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_DATE)
                info.external_attr = 0o644 << 16
                zf.writestr(info, buf.getvalue())


def read_npz(path: str | Path) -> dict[str, np.ndarray]:
    """All arrays of an ``.npz`` with pickles refused. Errors name the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    # np.load treats any non-zip bytes as a pickle; say what the file really is instead.
    if not zipfile.is_zipfile(path):
        raise ValueError(
            f"{path}: cannot be read as .npz (not a zip archive: truncated or not npz)"
        )
    try:
        with np.load(path, allow_pickle=False) as data:
            return {key: data[key] for key in data.files}
    except ValueError as exc:
        if "pickle" in str(exc).lower():
            raise ValueError(f"{path}: holds pickled objects, which are refused") from exc
        raise ValueError(f"{path}: cannot be read as .npz ({exc})") from exc
    except Exception as exc:  # damaged bytes surface as zip, struct, key or memory errors
        raise ValueError(f"{path}: cannot be read as .npz ({type(exc).__name__}: {exc})") from exc


def write_splits(folder: str | Path, splits: Mapping[str, list[str]]) -> None:
    """Write ``train.txt``, ``val.txt``, ``test.txt``: one flight file a line, named with its
    ``.npz`` suffix as the authors' release lists do (``baf_fast_00.npz``); a name that already
    ends in ``.npz`` is written as it is. The readers accept names with or without it."""
    for split in SPLITS:
        names = [n if n.lower().endswith(".npz") else f"{n}.npz" for n in splits.get(split, [])]
        write_text(Path(folder) / f"{split}.txt", "".join(f"{n}\n" for n in names))
