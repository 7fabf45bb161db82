"""The model's initial condition: causal estimates of the unmeasured load state.

The load velocity vL and the load angular velocity Omega_L are not measured; they are
estimated causally from the positions so that a prediction made at step k never uses a sample
after k: from the last two samples (``estimate_load_state``, the data's and the paper model's
estimate) or from a least-squares quadratic through the last few (``fit_load_state``, the
smoothed estimate). Pure batched torch beside ``physics``; the compiled copy in
``deploy.compiled.physics`` is held to these by parity tests. See ``docs/data.md``.
"""

from __future__ import annotations

import functools

import numpy as np
import torch
from torch import Tensor

from .config import VehicleParams
from .physics import per_window
from .smoothing import load_fit_coefficients
from .state import AUX_DIM, LOAD_RATE, LOAD_VEL, split_state


def estimate_load_state(states: np.ndarray | Tensor, params: VehicleParams) -> np.ndarray | Tensor:
    """Causal estimate of the unmeasured load state from positions, (..., T, 13) -> (..., T, 6).

    vL_k = (pL_k - pL_{k-1}) / h. With r = pL - p and xi_k = r_k / |r_k|,
    Omega_L,k = xi_k x (r_k - r_{k-1}) / (h l): the pendulum kinematics xi_dot = Omega_L x xi
    with Omega_L perpendicular to the cable. The relative velocity is the backward difference of
    r (not vL minus the measured v) so both positions carry the same half-step lag. Only
    samples k and k-1 are used; step 0 repeats step 1's difference (a forward difference).
    Returns numpy for numpy input, torch (same dtype/device) for torch input.
    """
    x = (
        torch.from_numpy(np.asarray(states, np.float64))
        if isinstance(states, np.ndarray)
        else states
    )
    if x.shape[-2] < 2:
        raise ValueError(f"estimate_load_state: need at least 2 time steps, got {x.shape[-2]}")
    p, _, _, p_load = split_state(x)
    rel = p_load - p
    xi = rel / rel.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    aux = x.new_empty(*x.shape[:-1], AUX_DIM)
    h = per_window(params.dt, rel)
    aux[..., LOAD_VEL] = _backward_difference(p_load, h)
    rel_rate = _backward_difference(rel, h)
    aux[..., LOAD_RATE] = torch.linalg.cross(xi, rel_rate) / per_window(params.cable_length, rel)
    return aux.numpy() if isinstance(states, np.ndarray) else aux


@functools.cache  # never freed: a captured CUDA graph may read one
def _fit_coefficients(steps: int, dt: float, dtype: torch.dtype, device: torch.device) -> Tensor:
    """``load_fit_coefficients`` as a tensor on ``device``, made once: a copy to a GPU at every
    call would also stop the call from being captured as a CUDA graph (``deploy.gpu``). A
    plain tensor even when first asked for under ``torch.inference_mode`` (an inference tensor
    could not be saved for a later backward pass)."""
    with torch.inference_mode(False):
        return torch.as_tensor(load_fit_coefficients(steps, dt), dtype=dtype).to(device)


def fit_load_state(states: Tensor, params: VehicleParams) -> Tensor:
    """Smoothed causal estimate of the load state at the last of K steps, (..., K, 13) ->
    (..., 6): vL and the rate of r = pL - p are the slopes of least-squares quadratics through
    the K samples (``load_fit_coefficients``), Omega_L = xi x r_dot / l with xi from the last
    sample, as ``estimate_load_state`` does with two samples. K >= 3."""
    dt = params.dt
    if isinstance(dt, Tensor):  # one per window: the filter needs one step
        if not bool((dt == dt.flatten()[0]).all()):
            raise ValueError("fit_load_state: the windows' time steps differ")
        dt = float(dt.flatten()[0])
    c = _fit_coefficients(states.shape[-2], float(dt), states.dtype, states.device)
    p, _, _, p_load = split_state(states)
    rel = p_load - p
    v_load = torch.einsum("k,...kd->...d", c, p_load)
    rel_rate = torch.einsum("k,...kd->...d", c, rel)
    xi = rel[..., -1, :] / rel[..., -1, :].norm(dim=-1, keepdim=True).clamp_min(1e-9)
    rate = torch.linalg.cross(xi, rel_rate) / per_window(params.cable_length, rel_rate)
    return torch.cat([v_load, rate], dim=-1)


def _backward_difference(y: Tensor, h: float | Tensor) -> Tensor:
    """(y_k - y_{k-1}) / h along axis -2, the first step repeating the second."""
    d = (y[..., 1:, :] - y[..., :-1, :]) / h
    return torch.cat([d[..., :1, :], d], dim=-2)
