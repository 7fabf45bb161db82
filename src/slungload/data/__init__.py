"""Flights on disk -> validated arrays -> estimated load state -> windows per split.

``flight`` (the ``Flight`` record, its checks and the load-state estimate), ``readers`` (one
per source format, flight files and logs), ``dataset`` (a folder with split lists:
``load_dataset``), ``windows`` (``make_windows``), ``cache`` (prepared flights on disk),
``summary`` (``slungload inspect``), ``split`` (the split policy), ``writer`` (the one dataset
writer), ``importing`` (``slungload import``).

The names below are resolved on first use (PEP 562), so that the CLI's help can read the split
policy without loading torch.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS: dict[str, tuple[str, ...]] = {
    "dataset": ("Dataset", "load_dataset", "read_splits"),
    "flight": ("DatasetError", "DataWarning", "Flight", "FlightFormatError",
               "estimate_load_state"),
    "readers": ("READERS", "read_flight"),
    "summary": ("DatasetSummary", "summarize"),
    "windows": ("Windows", "make_windows"),
}  # fmt: skip
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
