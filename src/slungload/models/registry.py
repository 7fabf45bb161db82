"""Model architectures by name: ``MODELS`` (name -> class) and ``build(config, params)``.

Every architecture maps a window's history and the future inputs to the predicted states
(``base.DynamicsModel``) and is built as ``cls(config, params)`` from a ``ModelConfig`` and the
vehicle constants alone, so a checkpoint that records ``ModelConfig.architecture`` is rebuilt
from the file. ``MODELS`` reads the one table, ``config.ARCHITECTURES`` (name -> "module:Class"),
and imports a class on first use: a new architecture is a module in this package and one line
there.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping

from torch import nn

from ..config import ARCHITECTURES, ModelConfig, VehicleParams


class _Architectures(Mapping[str, type[nn.Module]]):
    """name -> the network class ``config.ARCHITECTURES`` names, imported on first use."""

    def __getitem__(self, name: str) -> type[nn.Module]:
        module, cls_name = ARCHITECTURES[name].target.split(":")
        cls = getattr(importlib.import_module(f".{module}", __package__), cls_name)
        if getattr(cls, "architecture", None) != name:
            raise TypeError(f"{cls.__name__}.architecture must be {name!r}, the name it is "
                            "registered under")  # fmt: skip
        return cls

    def __iter__(self) -> Iterator[str]:
        return iter(ARCHITECTURES)

    def __len__(self) -> int:
        return len(ARCHITECTURES)


MODELS: Mapping[str, type[nn.Module]] = _Architectures()


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
