"""Flights on disk -> validated arrays -> estimated load state -> windows per split.

``flight`` (the ``Flight`` record, its checks and the load-state estimate), ``readers`` (one
per source format, flight files and logs), ``dataset`` (a folder with split lists:
``load_dataset``), ``windows`` (``make_windows``), ``cache`` (prepared flights on disk),
``summary`` (``slungload inspect``), ``split`` (the split policy), ``writer`` (the one dataset
writer), ``importing`` (``slungload import``), ``alignment`` (a second log on the first's
clock and frame).

The names below are resolved on first use (PEP 562), so that the CLI's help can read the split
policy without loading torch.
"""

from __future__ import annotations

from .._lazy import lazy_exports

_EXPORTS: dict[str, tuple[str, ...]] = {
    "dataset": ("Dataset", "load_dataset", "read_splits"),
    "flight": ("DatasetError", "DataWarning", "Flight", "FlightFormatError",
               "estimate_load_state"),
    "readers": ("READERS", "read_flight"),
    "summary": ("DatasetSummary", "summarize"),
    "windows": ("Windows", "make_windows"),
}  # fmt: skip
__all__, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())
