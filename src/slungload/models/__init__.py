"""Networks that predict the next N states: the architecture registry, the paper's network,
the physics-step network built on it, checkpoints that name their architecture (see
``registry`` for adding one), and the prediction-model contract that evaluation and control
predict with (``prediction``: the physics model and any registered network)."""

from .base import DynamicsModel, Prediction, count_parameters
from .checkpoints import LoadedModel, load_checkpoint
from .lstm_attention import SlungLoadNet
from .physics_step import PhysicsStepNet
from .prediction import (
    PHYSICS,
    NetworkModel,
    PhysicsModel,
    PredictionModel,
    load_prediction_model,
)
from .registry import MODELS, architecture_of, build, get_model_class, require_architecture

__all__ = [
    "MODELS",
    "PHYSICS",
    "DynamicsModel",
    "LoadedModel",
    "NetworkModel",
    "PhysicsModel",
    "PhysicsStepNet",
    "Prediction",
    "PredictionModel",
    "SlungLoadNet",
    "architecture_of",
    "build",
    "count_parameters",
    "get_model_class",
    "load_checkpoint",
    "load_prediction_model",
    "require_architecture",
]
