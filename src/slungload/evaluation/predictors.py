"""Evaluation on the test flights: errors per state group, MAE per horizon step with quartiles,
the RMSE table, batch-1 inference time, and the paper's numbers to compare with.

Read top to bottom: the paper's numbers, predictors (physics-only and network, one signature
over a batch of windows), error metrics, timing, the typed ``Report``, and the entry
``evaluate`` that loads runs and a dataset, runs every predictor at every horizon and (with
``out``) writes the report (``report.write_report``).

Metrics (the paper's Section IV-B), per group g of ``state.GROUPS`` (position, velocity,
quaternion, load position), with W test windows and horizon N::

    e_g[j, k] = || x_hat_g[j, k] - x_g[j, k] ||       (quaternion: || q_hat (x) q^-1 - q_id ||)
    MAE_g[k]  = mean_j e_g[j, k], with Q1 / Q3 the 25th / 75th percentiles over j
    RMSE_g    = sqrt( sum_{j,k} e_g[j, k]^2 / (W N) ),  combined = sum of the four RMSE_g

The quaternion error is the paper's: it is not sign-invariant (q and -q differ by 2); the
data are sign-continuous (``state.quat_continuous``) and both predictors continue the sign of
the last measured quaternion, so no sign ambiguity arises. Network quaternions are normalised
before the error is taken (the slack variables are ignored).

Horizon step k = 1 ... N predicts x_{M-1+k}, i.e. k dt seconds ahead.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import torch
from torch import Tensor, nn

from ..config import VehicleParams
from ..data.windows import Windows
from ..physics import rollout
from ..state import QUAT, quat_normalize


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
    (vL, Omega_L) and the true inputs u_{M-1} ... u_{M+N-2}; float64 inside.
    """

    params: VehicleParams
    batch_size: int = 8192

    def __call__(self, windows: Windows) -> Tensor:
        m, n = windows.window.history, windows.window.horizon
        out = []
        for i in range(0, len(windows), self.batch_size):
            w = windows[i : i + self.batch_size]
            x0 = w.states[:, m - 1].double()
            aux0 = w.aux[:, m - 1].double()
            inputs = w.inputs[:, m - 1 : m + n - 1].double()
            states, _ = rollout(x0, aux0, inputs, self.params)
            out.append(states.to(windows.states.dtype))
        return _cat(out, windows)


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
                out.append(unit_quaternion(pred.states).float().cpu())
        return _cat(out, windows)


def unit_quaternion(states: Tensor) -> Tensor:
    """States (..., 13) with the quaternion block normalised (evaluation only)."""
    out = states.clone()
    out[..., QUAT] = quat_normalize(states[..., QUAT])
    return out


def _cat(parts: list[Tensor], windows: Windows) -> Tensor:
    if parts:
        return torch.cat(parts)
    return windows.states.new_zeros(0, windows.window.horizon, windows.states.shape[-1])
