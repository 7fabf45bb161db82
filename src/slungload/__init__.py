"""slungload: physics-informed learned dynamics of a quadrotor carrying a cable-slung load."""

from .config import LossWeights, ModelConfig, TrainConfig, VehicleParams, WindowConfig
from .physics import rollout, step
from .state import GROUPS, INPUT_DIM, STATE_DIM

__version__ = "0.1.0"

__all__ = [
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
