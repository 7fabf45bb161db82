"""slungload: physics-informed learned dynamics of a quadrotor carrying a cable-slung load."""

from .config import LossWeights, ModelConfig, TrainConfig, VehicleParams, WindowConfig
from .data import (
    Dataset,
    DatasetError,
    DatasetSummary,
    Flight,
    FlightFormatError,
    estimate_load_state,
    load_dataset,
    read_flight,
    read_splits,
    summarize,
)
from .physics import rollout, step
from .state import GROUPS, INPUT_DIM, STATE_DIM

__version__ = "0.1.0"

from .windows import Windows, make_windows

__all__ = [
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
    "GROUPS",
    "INPUT_DIM",
    "STATE_DIM",
    "LossWeights",
    "ModelConfig",
    "TrainConfig",
    "VehicleParams",
    "WindowConfig",
    "__version__",
    "rollout",
    "step",
]
