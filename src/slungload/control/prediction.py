"""Prediction models for the MPC behind one interface: the physics model and trained networks.

Contract (``PredictionModel``)::

    model.predict(x_hist (M, 13), u_past (M - 1, 4), plans (K, N, 4)) -> states (K, N, 13)

x_hist holds the last M measured states x_{k-M+1} ... x_k (w-x-y-z quaternions, physical
units), u_past the inputs applied at x_{k-M+1} ... x_{k-1}, and plans K candidate input
sequences u_k ... u_{k+N-1} (u_k is applied at x_k, the step being decided). The result is
the predicted x_{k+1} ... x_{k+N} per candidate, with unit quaternions. ``model.history`` is
the M it needs; ``model.name`` labels it in reports.

- ``PhysicsModel``: ``physics.rollout`` from x_k with the causal load-state estimate from the
  last two measured states (``data.flight.estimate_load_state``, as the physics baseline).
- ``NetworkModel``: any registered architecture (``models.MODELS``) through its
  ``forward_candidates(x_hist, u_past, plans)``: the network's window pairs x_j with u_j, so
  its history's last input row is the candidate u_k; the encoder runs once over the M - 1
  rows every candidate shares and only its last step and the decoder run at batch K (equal
  to ``forward`` per candidate, a test holds it).

``History`` is the buffer the controller keeps: measured states and applied inputs, padded
with the first row until M steps have been seen.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np
import torch
from torch import Tensor, nn

from .. import physics
from ..config import VehicleParams
from ..data.flight import estimate_load_state
from ..models.checkpoints import load_checkpoint
from ..state import INPUT_DIM, STATE_DIM, with_unit_quaternion

PHYSICS = "physics"  # the name that selects the physics model (``load_prediction_model``)


@runtime_checkable
class PredictionModel(Protocol):
    """What the MPC predicts with (see the module)."""

    name: str
    history: int  # M: measured states the model needs (>= 2)

    def predict(self, x_hist: Tensor, u_past: Tensor, plans: Tensor) -> Tensor: ...


@dataclass
class PhysicsModel:
    """The paper's discrete model rolled out from the last measured state (float64)."""

    params: VehicleParams
    name: str = PHYSICS
    history: int = 2

    def predict(self, x_hist: Tensor, u_past: Tensor, plans: Tensor) -> Tensor:
        _check(x_hist, u_past, plans)
        x_hist = x_hist.to(plans.dtype)
        aux = estimate_load_state(x_hist[-2:], self.params)[-1]  # (6,) causal, steps k-1 and k
        k = plans.shape[0]
        states, _ = physics.rollout(
            x_hist[-1].expand(k, STATE_DIM), aux.expand(k, aux.shape[-1]), plans, self.params
        )
        return states


@dataclass
class NetworkModel:
    """A trained network (any registered architecture) in eval mode, physical units."""

    net: nn.Module
    history: int
    name: str = "network"

    def __post_init__(self) -> None:
        self.net.eval()
        self.dtype = next(self.net.parameters()).dtype

    def predict(self, x_hist: Tensor, u_past: Tensor, plans: Tensor) -> Tensor:
        _check(x_hist, u_past, plans)
        with torch.inference_mode():
            states = self.net.forward_candidates(
                x_hist.to(self.dtype), u_past.to(self.dtype), plans.to(self.dtype)
            ).states
        return with_unit_quaternion(states).to(plans.dtype)


def load_prediction_model(spec: str | Path, params: VehicleParams | None = None) -> PredictionModel:
    """``"physics"`` (the discrete model with ``params``, default ``VehicleParams()``), or a
    run folder / ``.ckpt`` of any registered architecture, named after its folder."""
    if str(spec) == PHYSICS:
        return PhysicsModel(params or VehicleParams())
    loaded = load_checkpoint(spec)
    path = Path(spec)
    label = path.name if path.is_dir() else path.parent.name
    return NetworkModel(loaded.model, loaded.window.history, name=label)


class History:
    """The last M measured states and the inputs applied at them (numpy, float64).

    ``push_state(x)`` at each control step before deciding, ``push_input(u)`` after. Until M
    states have been seen, the window is padded with the first state and input (the flight
    starts in hover).
    """

    def __init__(self, m: int) -> None:
        if m < 2:
            raise ValueError(f"History: need M >= 2, got {m}")
        self.m = m
        self.states: list[np.ndarray] = []
        self.inputs: list[np.ndarray] = []

    def push_state(self, x: np.ndarray) -> None:
        self.states = [*self.states, np.asarray(x, dtype=float)][-self.m :]

    def push_input(self, u: np.ndarray) -> None:
        self.inputs = [*self.inputs, np.asarray(u, dtype=float)][-(self.m - 1) :]

    def window(self, first_input: np.ndarray) -> tuple[Tensor, Tensor]:
        """x_hist (M, 13) and u_past (M-1, 4) as float64 tensors; ``first_input`` pads the
        inputs before any was applied."""
        if not self.states:
            raise ValueError("History: no state pushed yet")
        xs = [self.states[0]] * (self.m - len(self.states)) + self.states
        us = self.inputs or [np.asarray(first_input, dtype=float)]
        us = [us[0]] * (self.m - 1 - len(us)) + us
        return torch.from_numpy(np.stack(xs)), torch.from_numpy(np.stack(us[-(self.m - 1) :]))


def _check(x_hist: Tensor, u_past: Tensor, plans: Tensor) -> None:
    ok = (
        x_hist.dim() == 2
        and x_hist.shape[1] == STATE_DIM
        and x_hist.shape[0] >= 2
        and u_past.shape == (x_hist.shape[0] - 1, INPUT_DIM)
        and plans.dim() == 3
        and plans.shape[-1] == INPUT_DIM
    )
    if not ok:
        raise ValueError(
            f"predict: expected x_hist (M>=2, {STATE_DIM}), u_past (M-1, {INPUT_DIM}), plans "
            f"(K, N, {INPUT_DIM}); got {tuple(x_hist.shape)}, {tuple(u_past.shape)}, "
            f"{tuple(plans.shape)}"
        )
