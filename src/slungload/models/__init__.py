"""Networks that predict the next N states: the architecture registry, the paper's network,
the physics-step network built on it, and checkpoints that name their architecture (see
``registry`` for adding one)."""

from .base import DynamicsModel, Prediction, count_parameters
from .checkpoints import LoadedModel, load_checkpoint
from .lstm_attention import SlungLoadNet
from .physics_step import PhysicsStepNet
from .registry import MODELS, architecture_of, build, get_model_class, require_architecture

__all__ = [
    "MODELS",
    "DynamicsModel",
    "LoadedModel",
    "PhysicsStepNet",
    "Prediction",
    "SlungLoadNet",
    "architecture_of",
    "build",
    "count_parameters",
    "get_model_class",
    "load_checkpoint",
    "require_architecture",
]
