"""The four-term physics-informed loss (the paper's Section III-B) and its ablation variants.

    L = L_fit + L_physics + L_projection + L_slack

With the horizon index n = 0 ... N-1 standing for the steps M ... M+N-1 (so the paper's
e^{-alpha (n - M)} is e^{-alpha n} here)::

    L_fit        = sum_n e^{-alpha n} (l1 |p^-p|^2 + l2 |v^-v|^2 + l3 |e(q^, q)|^2 + l4 |pL^-pL|^2)
                   (each group's term times c_g / s_gn with the "physics-relative" steps)
    L_physics    = phi sum_n e^{-beta n} |x^_n - f(x_{n-1}, u_{n-1}, a_{n-1}) + s_n|^2
    L_projection = psi sum_n (1 - |q^_n|)^2
    L_slack      = rho sum_n e^{-beta n} |s_n|^2

where e(q1, q2) = q1 (x) q2^{-1} - q_id, f is ``physics.step``, and the argument of f is the
last measured state x_{M-1} for n = 0 and the prediction x^_{n-1} for n >= 1, with the actual
input and the data's estimate of the load state a = (vL, Omega_L) at that step. The quaternion
part of the physics residual is multiplicative, e(q^_n, q_f). Each term is summed over the
horizon and averaged over the batch, in physical units.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import torch
from torch import Tensor

from .config import LOSS_VARIANTS, LossVariant, LossWeights, ModelConfig, VehicleParams
from .models.base import Prediction
from .physics import step
from .state import AUX_DIM, GROUPS, INPUT_DIM, LOAD_POS, POS, QUAT, STATE_DIM, VEL, quat_error


class LossTerms(NamedTuple):
    """The loss and its four terms, scalar tensors (a term that is off is zero)."""

    total: Tensor
    fit: Tensor
    physics: Tensor
    projection: Tensor
    slack: Tensor

    def scalars(self) -> dict[str, float]:
        """Plain floats for logging."""
        return {name: float(value.detach()) for name, value in self._asdict().items()}


def get_variant(name: str) -> LossVariant:
    """The registered variant ``name``; unknown names list the known ones."""
    try:
        return LOSS_VARIANTS[name]
    except KeyError:
        raise ValueError(
            f"unknown loss variant {name!r}; known: {', '.join(LOSS_VARIANTS)}"
        ) from None


def model_config_for(variant: str, base: ModelConfig) -> ModelConfig:
    """``base`` with ``slack`` set as the variant needs."""
    return dataclasses.replace(base, slack=get_variant(variant).slack)


# --- the terms ---------------------------------------------------------------------------


def horizon_weights(n: int, rate: float, like: Tensor) -> Tensor:
    """e^{-rate k} for k = 0 ... n-1, (n,), dtype and device of ``like``."""
    k = torch.arange(n, dtype=like.dtype, device=like.device)
    return torch.exp(-rate * k)


def fit_loss(
    states_hat: Tensor, truth: Tensor, weights: LossWeights, scale: Tensor | None = None
) -> Tensor:
    """L_fit, scalar: states_hat, truth (B, N, 13), physical units; mean over the batch.

    scale: optional (4, N) factors on each group's (``state.GROUPS`` order) squared error at
    each step, e.g. ``physics_relative_scale``; None for the paper's loss.
    """
    groups = (
        (states_hat[..., POS] - truth[..., POS]).square().sum(-1),
        (states_hat[..., VEL] - truth[..., VEL]).square().sum(-1),
        quat_error(states_hat[..., QUAT], truth[..., QUAT]).square().sum(-1),
        (states_hat[..., LOAD_POS] - truth[..., LOAD_POS]).square().sum(-1),
    )  # 4 x (B, N)
    lambdas = (weights.position, weights.velocity, weights.quaternion, weights.load_position)
    if scale is None:
        per_step = sum(w * g for w, g in zip(lambdas, groups, strict=True))  # (B, N)
    else:
        per_step = sum(w * g * s for w, g, s in zip(lambdas, groups, scale, strict=True))
    decay = horizon_weights(per_step.shape[-1], weights.alpha, per_step)
    return (per_step * decay).sum(-1).mean()


def step_scale(steps: str, physics_mse: Tensor, alpha: float) -> Tensor:
    """The (4, N) ``fit_loss`` factors of a step weighting (``config.STEP_WEIGHTINGS``) other
    than the paper's: "physics-relative" (``physics_relative_scale``) or "mixed" (its mean
    with the paper's factor 1)."""
    relative = physics_relative_scale(physics_mse, alpha)
    if steps == "physics-relative":
        return relative
    if steps == "mixed":
        return 0.5 * (1.0 + relative)
    raise ValueError(f"step weighting {steps!r} has no fit_scale (known: physics-relative, mixed)")


def physics_relative_scale(physics_mse: Tensor, alpha: float) -> Tensor:
    """The "physics-relative" step weighting: (4, N) factors c_g / s_gn for ``fit_loss``.

    physics_mse (4, N): s_gn, the physics model's mean-square error of group g (``GROUPS``
    order, squared group unit) at horizon step n on the training windows. With
    c_g = sum_n e^{-alpha n} s_gn / sum_n e^{-alpha n}, errors at the physics model's level
    give the paper's L_fit, spread evenly over the steps (times the decay) instead of falling
    mostly on the late ones: the early steps, where the physics model is already good, weigh
    as much as the late ones.
    """
    if physics_mse.dim() != 2 or physics_mse.shape[0] != len(GROUPS):
        raise ValueError(f"physics_mse must be ({len(GROUPS)}, N), got {tuple(physics_mse.shape)}")
    s = physics_mse.double().clamp_min(1e-12)  # a perfect step would get an infinite weight
    decay = horizon_weights(s.shape[-1], alpha, s)
    c = (s * decay).sum(-1, keepdim=True) / decay.sum()
    return (c / s).to(physics_mse.dtype)


def physics_residual(
    states_hat: Tensor,
    slack: Tensor | None,
    x_last: Tensor,
    inputs: Tensor,
    aux: Tensor,
    params: VehicleParams,
) -> Tensor:
    """x^_n - f(x_{n-1}, u_{n-1}, a_{n-1}) + s_n, (B, N, 13), quaternion part multiplicative.

    states_hat (B, N, 13) predictions x^_M ... x^_{M+N-1}; slack (B, N, 13) or None (zero);
    x_last (B, 13) the last measured state x_{M-1}; inputs (B, N, 4) u_{M-1} ... u_{M+N-2};
    aux (B, N, 6) the data's (vL, Omega_L) at steps M-1 ... M+N-2.
    """
    previous = torch.cat([x_last.unsqueeze(1), states_hat[:, :-1]], dim=1)  # (B, N, 13)
    f, _ = step(previous, inputs, aux, params)  # (B, N, 13), one batched call
    residual = states_hat - f
    # q^ (x) q_f^{-1} - q_id replaces the difference in the quaternion block.
    residual = torch.cat(
        [
            residual[..., : QUAT.start],
            quat_error(states_hat[..., QUAT], f[..., QUAT]),
            residual[..., QUAT.stop :],
        ],
        dim=-1,
    )
    return residual if slack is None else residual + slack


def physics_loss(residual: Tensor, weights: LossWeights) -> Tensor:
    """L_physics, scalar, from ``physics_residual`` (B, N, 13); mean over the batch."""
    per_step = residual.square().sum(-1)  # (B, N)
    decay = horizon_weights(per_step.shape[-1], weights.beta, per_step)
    return weights.physics * (per_step * decay).sum(-1).mean()


def projection_loss(states_hat: Tensor, weights: LossWeights) -> Tensor:
    """L_projection, scalar: psi sum_n (1 - |q^_n|)^2 for states_hat (B, N, 13)."""
    norm = states_hat[..., QUAT].norm(dim=-1)  # (B, N)
    return weights.projection * (1.0 - norm).square().sum(-1).mean()


def slack_loss(slack: Tensor, weights: LossWeights) -> Tensor:
    """L_slack, scalar: rho sum_n e^{-beta n} |s_n|^2 for slack (B, N, 13)."""
    per_step = slack.square().sum(-1)  # (B, N)
    decay = horizon_weights(per_step.shape[-1], weights.beta, per_step)
    return weights.slack * (per_step * decay).sum(-1).mean()


# --- entry -------------------------------------------------------------------------------


def compute_loss(
    pred: Prediction,
    states: Tensor,
    inputs: Tensor,
    aux: Tensor,
    *,
    history: int,
    params: VehicleParams,
    weights: LossWeights,
    variant: str = "proposed",
    fit_scale: Tensor | None = None,
) -> LossTerms:
    """The training loss of one batch of windows.

    pred: the network's output over the horizon, states (B, N, 13) and slack (B, N, 13) or
    None; states (B, M+N, 13), inputs (B, M+N, 4), aux (B, M+N, 6) = (vL, Omega_L): the
    whole windows in physical units; history: M. fit_scale: (4, N) step factors of L_fit
    (``step_scale``), needed when ``weights.steps`` is not "paper".
    """
    v = get_variant(variant)
    x_hat = pred.states
    b, n = x_hat.shape[0], x_hat.shape[1]
    m = history
    expected = {"states": STATE_DIM, "inputs": INPUT_DIM, "aux": AUX_DIM}
    for name, tensor in (("states", states), ("inputs", inputs), ("aux", aux)):
        if tensor.dim() != 3 or tensor.shape[0] != b or tensor.shape[1] != m + n:
            raise ValueError(
                f"compute_loss: {name} must be (B={b}, M+N={m + n}, {expected[name]}), "
                f"got {tuple(tensor.shape)}"
            )
    if m < 1:
        raise ValueError(f"compute_loss: history must be >= 1, got {m}")
    if v.slack and pred.slack is None:
        raise ValueError(f"loss variant {variant!r} needs a model built with slack=True")
    if not v.slack and pred.slack is not None:
        raise ValueError(
            f"loss variant {variant!r} needs a model built with slack=False (see model_config_for)"
        )

    if (weights.steps == "paper") != (fit_scale is None):
        raise ValueError(
            f"compute_loss: step weighting {weights.steps!r} "
            + ("takes no fit_scale" if fit_scale is not None else "needs fit_scale")
        )
    if fit_scale is not None and tuple(fit_scale.shape) != (len(GROUPS), n):
        raise ValueError(
            f"compute_loss: fit_scale must be ({len(GROUPS)}, N={n}), got {tuple(fit_scale.shape)}"
        )
    zero = x_hat.new_zeros(())
    fit = fit_loss(x_hat, states[:, m:], weights, fit_scale)
    projection = projection_loss(x_hat, weights)
    physics, slack = zero, zero
    if v.physics:
        residual = physics_residual(
            x_hat, pred.slack, states[:, m - 1], inputs[:, m - 1 : -1], aux[:, m - 1 : -1], params
        )
        physics = physics_loss(residual, weights)
    if v.slack:
        slack = slack_loss(pred.slack, weights)
    return LossTerms(fit + physics + projection + slack, fit, physics, projection, slack)
