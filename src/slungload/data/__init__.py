"""Flights on disk -> validated arrays -> estimated load state -> windows per split.

``flight`` (the ``Flight`` record, its checks and the load-state estimate), ``readers`` (one
per source format), ``dataset`` (a folder with split lists: ``load_dataset``), ``windows``
(``make_windows``), ``cache`` (prepared flights on disk), ``summary`` (``slungload inspect``).
"""

from .dataset import Dataset, load_dataset, read_splits
from .flight import DatasetError, DataWarning, Flight, FlightFormatError, estimate_load_state
from .readers import READERS, read_flight
from .summary import DatasetSummary, summarize
from .windows import Windows, make_windows

__all__ = [
    "READERS",
    "DataWarning",
    "Dataset",
    "DatasetError",
    "DatasetSummary",
    "Flight",
    "FlightFormatError",
    "Windows",
    "estimate_load_state",
    "load_dataset",
    "make_windows",
    "read_flight",
    "read_splits",
    "summarize",
]
