"""Predictors evaluated on test windows, one signature over a batch of windows: the
physics-only open-loop rollout (the paper's "physics" row) and a trained network.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import torch
from torch import Tensor, nn

from ..config import VehicleParams
from ..data.windows import Windows, physics_rollout
from ..state import with_unit_quaternion


class Predictor(Protocol):
    """Predicts the N future states of a batch of windows.

    windows: states (W, M+N, 13), inputs (W, M+N, 4), aux (W, M+N, 6); only the history, the
    inputs and the aux at the last history step may be used. Returns (W, N, 13)
    x_hat_M ... x_hat_{M+N-1}, physical units, unit quaternion w-x-y-z.
    """

    def __call__(self, windows: Windows) -> Tensor: ...


@dataclass
class PhysicsPredictor:
    """Open-loop physics-only prediction (the paper's "physics" row).

    Rolls ``physics.rollout`` from the last measured state x_{M-1} with its estimated
    (vL, Omega_L) and the true inputs u_{M-1} ... u_{M+N-2} (``data.windows.physics_rollout``,
    which training shares); float64 inside.
    """

    params: VehicleParams
    batch_size: int = 8192

    def __call__(self, windows: Windows) -> Tensor:
        return physics_rollout(windows, self.params, self.batch_size).to(windows.states.dtype)


@dataclass
class NetworkPredictor:
    """A trained network (``forward(x_hist, u_hist, u_future) -> Prediction``), batched.

    The network runs in eval mode under ``torch.inference_mode``; its quaternion is normalised
    and its slack variables are ignored.
    """

    model: nn.Module
    batch_size: int = 1024
    device: str | torch.device = "cpu"

    def __call__(self, windows: Windows) -> Tensor:
        m = windows.window.history
        self.model.eval()
        self.model.to(self.device)
        out = []
        with torch.inference_mode():
            for i in range(0, len(windows), self.batch_size):
                w = windows[i : i + self.batch_size].to(self.device)
                pred = self.model(w.states[:, :m], w.inputs[:, :m], w.inputs[:, m:])
                out.append(with_unit_quaternion(pred.states).float().cpu())
        return _cat(out, windows)


def _cat(parts: list[Tensor], windows: Windows) -> Tensor:
    if parts:
        return torch.cat(parts)
    return windows.states.new_zeros(0, windows.window.horizon, windows.states.shape[-1])
