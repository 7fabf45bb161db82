"""Deprecated names of the evaluation's predictors, kept for the public API.

Evaluation now predicts with ``models.prediction``'s ``PhysicsModel`` and ``NetworkModel``
through ``predict_windows``. ``PhysicsPredictor(params)(windows)`` and
``NetworkPredictor(model)(windows)`` still work (they return that bound method) and warn.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import torch
from torch import Tensor, nn

from ..config import VehicleParams
from ..data.windows import Windows
from ..models.prediction import NetworkModel, PhysicsModel


def PhysicsPredictor(  # noqa: N802 (the old class name)
    params: VehicleParams, batch_size: int = 8192
) -> Callable[[Windows], Tensor]:
    """Deprecated: ``PhysicsModel(params, batch_size=...).predict_windows``."""
    _warn("PhysicsPredictor", "PhysicsModel")
    return PhysicsModel(params, batch_size=batch_size).predict_windows


def NetworkPredictor(  # noqa: N802 (the old class name)
    model: nn.Module, batch_size: int = 1024, device: str | torch.device = "cpu"
) -> Callable[[Windows], Tensor]:
    """Deprecated: ``NetworkModel(model, history, batch_size=..., device=...).predict_windows``
    (the windows' own M is used, as before)."""
    _warn("NetworkPredictor", "NetworkModel")
    history = 0  # unknown here; predict_windows uses the windows' own M
    return NetworkModel(model, history, batch_size=batch_size, device=device).predict_windows


def _warn(old: str, new: str) -> None:
    warnings.warn(
        f"slungload.{old} is deprecated; use slungload.{new}(...).predict_windows",
        DeprecationWarning,
        stacklevel=3,
    )
