"""The paper's discretised quadrotor + slung-load model f(x, u, Omega_L), batched torch.

Written once and used by the physics loss, the physics-only predictor and any export.

Frame: world z **up**, gravity ``-g e3`` (the data's convention). The paper prints the model
with gravity ``+g e3`` and a vehicle update ``u_bar + u_star`` whose gravity terms disagree;
Newton's law (and the authors' code) gives, in z up, with xi = (pL - p) / l pointing from the
vehicle to the load and the cable tension T_L::

    vehicle acceleration  a  = (T / mQ) R e3 - g e3 + (T_L / mQ) xi
    load acceleration     aL = -(T_L / mL) xi - g e3
    tension               T_L = -(mL / (mL + mQ)) T xi^T R e3 + (mL mQ / (mL + mQ)) l |Omega_L|^2
    load rate             Omega_L+ = (1 - d) Omega_L - h / (mQ l) S(xi) R T e3

and the discrete updates p+ = p + h v + h^2/2 a, v+ = v + h a (same for the load), and
R+ = R exp(h S(omega)), i.e. q+ = q (x) exp(h omega / 2). The tension follows from the taut
cable constraint (it is the paper's formula); it is not clipped at zero, as in the paper: the
model assumes a taut cable and leaves slack to the learned part. T is the commanded thrust
times ``params.thrust_gain`` (1 in the paper; fitted by ``slungload identify``).

``params`` is a ``VehicleParams`` or a ``VehicleConstants``, the constants' tensor view: one set
as floats (a dataset's), as 0-d tensors (``models.constants.LearnedConstants.current()``, fitted
by gradient) or one set per window (``VehicleConstants.stack``): tensors of the states' leading
shape, e.g. (B,) for x (B, 13), so that a constant of shape (B,) scales a (B, 3) vector as
(B, 1). Python floats stay floats, so the one-set path is the same arithmetic as with
``VehicleParams``.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .config import VehicleParams
from .state import (
    LOAD_RATE,
    LOAD_VEL,
    body_z,
    join_state,
    quat_from_rotvec,
    quat_mul,
    quat_normalize,
    split_input,
    split_state,
)
from .vehicle_constants import Constant, VehicleConstants

Vehicle = VehicleParams | VehicleConstants  # what the functions below take as ``params``


def per_window(c: Constant, like: Tensor) -> Constant:
    """A constant ready to scale ``like`` (B, ..., 3): floats and 0-d tensors as they are, one
    value per window (B,) as (B, 1, ..., 1)."""
    if not isinstance(c, Tensor) or c.dim() == 0:
        return c
    return c.reshape(*c.shape, *(1,) * (like.dim() - c.dim()))


def cable_direction(p: Tensor, p_load: Tensor, params: Vehicle) -> Tensor:
    """xi = (pL - p) / l, (..., 3): unit when the cable is at its nominal length."""
    return (p_load - p) / per_window(params.cable_length, p)


def thrust_vector(q: Tensor, thrust: Tensor) -> Tensor:
    """T R e3 in the world frame, N: q (..., 4) w-x-y-z, thrust (...,) -> (..., 3)."""
    return body_z(q) * thrust.unsqueeze(-1)


def tension(xi: Tensor, thrust_w: Tensor, load_rate: Tensor, params: Vehicle) -> Tensor:
    """Cable tension T_L, N, (...,) from xi (..., 3), T R e3 (..., 3) and Omega_L (..., 3)."""
    mq, ml, length = params.mass_quad, params.mass_load, params.cable_length
    m_sum = mq + ml
    along = (xi * thrust_w).sum(-1)
    return -(ml / m_sum) * along + (ml * mq / m_sum) * length * load_rate.square().sum(-1)


def accelerations(
    x: Tensor, u: Tensor, load_rate: Tensor, params: Vehicle
) -> tuple[Tensor, Tensor, Tensor]:
    """Vehicle and load accelerations, m/s^2, and the load-rate derivative, rad/s^2.

    x (..., 13), u (..., 4), load_rate Omega_L (..., 3) -> a (..., 3), aL (..., 3),
    dOmega_L/dt (..., 3) without damping.
    """
    p, _, q, p_load = split_state(x)
    thrust, _ = split_input(u)
    xi = cable_direction(p, p_load, params)
    thrust_w = thrust_vector(q, params.thrust_gain * thrust)
    t_load = tension(xi, thrust_w, load_rate, params).unsqueeze(-1)
    mq, ml = per_window(params.mass_quad, p), per_window(params.mass_load, p)
    g = torch.zeros_like(p)
    g[..., 2] = params.gravity
    acc = thrust_w / mq - g + (t_load / mq) * xi
    acc_load = -(t_load / ml) * xi - g
    rate_dot = -torch.linalg.cross(xi, thrust_w) / (mq * per_window(params.cable_length, p))
    return acc, acc_load, rate_dot


def step(x: Tensor, u: Tensor, aux: Tensor, params: Vehicle) -> tuple[Tensor, Tensor]:
    """One step of the discrete model: (x_k, u_k, a_k) -> (x_{k+1}, a_{k+1}).

    x (..., 13) state, u (..., 4) input, aux (..., 6) = (vL, Omega_L) the unmeasured load
    velocity (m/s) and load angular velocity (rad/s). Leading dimensions broadcast, the
    constants' too (one per window: shape (B,) for x (B, 13); see the module's docstring).
    The returned quaternion is renormalised.
    """
    p, v, q, p_load = split_state(x)
    h = per_window(params.dt, p)
    _, rates = split_input(u)
    v_load, load_rate = aux[..., LOAD_VEL], aux[..., LOAD_RATE]
    acc, acc_load, rate_dot = accelerations(x, u, load_rate, params)
    p_next = p + h * v + 0.5 * h * h * acc
    v_next = v + h * acc
    p_load_next = p_load + h * v_load + 0.5 * h * h * acc_load
    v_load_next = v_load + h * acc_load
    q_next = quat_normalize(quat_mul(q, quat_from_rotvec(h * rates)))
    rate_next = (1.0 - per_window(params.load_damping, p)) * load_rate + h * rate_dot
    x_next = join_state(p_next, v_next, q_next, p_load_next)
    return x_next, torch.cat([v_load_next, rate_next], dim=-1)


def rollout(x0: Tensor, aux0: Tensor, inputs: Tensor, params: Vehicle) -> tuple[Tensor, Tensor]:
    """Open-loop physics-only prediction (the paper's "physics" row).

    x0 (..., 13) last measured state x_{M-1}; aux0 (..., 6) its estimated (vL, Omega_L);
    inputs (..., N, 4) the true inputs u_{M-1} ... u_{M+N-2}; params one set of constants or
    one per window (shaped as x0's leading dimensions).
    Returns states (..., N, 13) = x_M ... x_{M+N-1} and aux (..., N, 6).
    """
    states, auxes = [], []
    x, aux = x0, aux0
    for k in range(inputs.shape[-2]):
        x, aux = step(x, inputs[..., k, :], aux, params)
        states.append(x)
        auxes.append(aux)
    return torch.stack(states, dim=-2), torch.stack(auxes, dim=-2)


def hover_thrust(params: VehicleParams) -> float:
    """Thrust, N, that holds vehicle and hanging load still: (mQ + mL) g."""
    return (params.mass_quad + params.mass_load) * params.gravity
