"""The on-disk cache of prepared flights (``data.load_dataset``).

A ``torch.save`` file of the validated flights with their load-state estimates and split
lists, plain tensors, strings and dicts, read back with ``weights_only=True``; windows are
re-cut from them on loading. Its name is a hash of everything the windows depend on (see
``cache_key``), so a stale cache is never read, only left behind.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import torch

from ..config import VehicleParams, WindowConfig, to_dict
from ..fileio import atomic_path

# Bump when the windows or the cache layout change: old cache files are then never read.
CACHE_VERSION = 2  # 2: flights only, no windows
CACHE_ENV = "SLUNGLOAD_CACHE"


def default_cache_dir() -> Path:
    """``$SLUNGLOAD_CACHE`` if set, else ``~/.cache/slungload``."""
    env = os.environ.get(CACHE_ENV)
    return Path(env) if env else Path.home() / ".cache" / "slungload"


def cache_key(files: Iterable[Path], window: WindowConfig, params: VehicleParams) -> str:
    """SHA-256 over the cache version, window config, vehicle constants and the name and
    bytes of every file (flights and split lists), in the given order."""
    h = hashlib.sha256()
    meta = {"version": CACHE_VERSION, "window": to_dict(window), "params": to_dict(params)}
    h.update(json.dumps(meta, sort_keys=True).encode())
    for path in files:
        data = Path(path).read_bytes()
        h.update(f"\0{Path(path).name}\0{len(data)}\0".encode())
        h.update(data)
    return h.hexdigest()


def save_cache(path: Path, key: str, payload: dict[str, Any]) -> None:
    """Write a cache file atomically (a crash never leaves a half-written cache)."""
    with atomic_path(path) as tmp:
        torch.save({"version": CACHE_VERSION, "key": key, "payload": payload}, tmp)


def load_cache(path: Path, key: str) -> dict[str, Any] | None:
    """The payload stored under ``key``, or None if the file is absent.

    Raises ValueError if the file exists but is unreadable or not the expected cache.
    """
    if not path.is_file():
        return None
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # any unpickling / zip error means the same: rebuild
        raise ValueError(f"{path}: unreadable cache ({type(exc).__name__}: {exc})") from exc
    if not isinstance(data, dict) or data.get("version") != CACHE_VERSION or data.get("key") != key:
        raise ValueError(f"{path}: not a cache file of version {CACHE_VERSION} for this dataset")
    return data["payload"]
