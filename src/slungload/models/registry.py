"""Model architectures by name: ``MODELS`` (name -> class) and ``build(config, params)``.

Every architecture maps a window's history and the future inputs to the predicted states
(``base.DynamicsModel``) and is built as ``cls(config, params)`` from a ``ModelConfig`` and the
vehicle constants alone, so a checkpoint that records ``ModelConfig.architecture`` is rebuilt
from the file. A new architecture is a module in this package and one line below.
"""

from __future__ import annotations

from torch import nn

from ..config import ModelConfig, VehicleParams
from .lstm_attention import SlungLoadNet
from .physics_step import PhysicsStepNet

MODELS: dict[str, type[nn.Module]] = {
    SlungLoadNet.architecture: SlungLoadNet,  # the paper's network
    PhysicsStepNet.architecture: PhysicsStepNet,  # the paper's network on f's step
}


def get_model_class(name: str) -> type[nn.Module]:
    """The class registered as ``name``; a clear error naming the known ones otherwise."""
    if name not in MODELS:
        raise ValueError(f"unknown model architecture {name!r}; known: {sorted(MODELS)}")
    return MODELS[name]


def build(config: ModelConfig, params: VehicleParams | None = None) -> nn.Module:
    """A fresh network of ``config.architecture`` (weights drawn from torch's generator)."""
    cls = get_model_class(config.architecture)
    return cls(config, params or VehicleParams())


def architecture_of(model: nn.Module) -> str:
    """The registered name of a network's architecture (``ValueError`` if unregistered)."""
    name = getattr(model, "architecture", None)
    if name not in MODELS or not isinstance(model, MODELS[name]):
        raise ValueError(
            f"{type(model).__name__} is not a registered architecture ({sorted(MODELS)})"
        )
    return name


def require_architecture(model: nn.Module, supported: tuple[str, ...], what: str) -> str:
    """Refuse, naming the architecture, a model that ``what`` (e.g. "the compiled predictor")
    does not support; never fall back to another network. Returns the architecture's name."""
    name = architecture_of(model)
    if name not in supported:
        raise ValueError(
            f"{what} does not support the {name!r} architecture (it supports {list(supported)})"
        )
    return name
