"""The four-term loss: exact zeros on model-consistent data, weights, variants, gradients."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from slungload.config import LossWeights, ModelConfig, VehicleParams
from slungload.loss import (
    LOSS_VARIANTS,
    LossTerms,
    compute_loss,
    fit_loss,
    model_config_for,
    physics_loss,
    physics_relative_scale,
    physics_residual,
    step_scale,
)
from slungload.models.base import Prediction
from slungload.models.lstm_attention import SlungLoadNet
from slungload.physics import hover_thrust, step
from slungload.state import GROUPS, POS, QUAT, join_state, quat_from_rotvec

torch.set_num_threads(1)

PARAMS = VehicleParams()
WEIGHTS = LossWeights()
M, N = 4, 6


def truth_windows(batch: int = 3, dtype=torch.float64, seed: int = 0):
    """Windows that obey the discrete model exactly: states, inputs, aux (B, M+N, .)."""
    g = torch.Generator().manual_seed(seed)
    p = torch.randn(batch, 3, generator=g, dtype=dtype)
    v = 0.5 * torch.randn(batch, 3, generator=g, dtype=dtype)
    q = quat_from_rotvec(0.2 * torch.randn(batch, 3, generator=g, dtype=dtype))
    xi = torch.tensor([0.1, -0.1, -1.0], dtype=dtype)
    xi = xi / xi.norm()
    x = join_state(p, v, q, p + PARAMS.cable_length * xi)
    a = torch.cat([v, 0.3 * torch.randn(batch, 3, generator=g, dtype=dtype)], dim=-1)
    u = torch.randn(batch, M + N, 4, generator=g, dtype=dtype) * 0.3
    u[..., 0] += hover_thrust(PARAMS)
    states, aux = [x], [a]
    for k in range(M + N - 1):
        x, a = step(x, u[:, k], a, PARAMS)
        states.append(x)
        aux.append(a)
    return torch.stack(states, 1), u, torch.stack(aux, 1)


def loss(pred, states, inputs, aux, variant="proposed", weights=WEIGHTS) -> LossTerms:
    return compute_loss(
        pred, states, inputs, aux, history=M, params=PARAMS, weights=weights, variant=variant
    )


def test_perfect_model_consistent_prediction_has_zero_loss():
    states, inputs, aux = truth_windows()
    pred = Prediction(states[:, M:].clone(), torch.zeros_like(states[:, M:]))
    terms = loss(pred, states, inputs, aux)
    for name in ("total", "fit", "physics", "projection", "slack"):
        assert getattr(terms, name).item() == pytest.approx(0.0, abs=1e-20), name


def test_physics_term_uses_predictions_after_the_first_step():
    """Only x_{M-1}, the inputs and aux enter from the data; later states come from pred."""
    states, inputs, aux = truth_windows()
    pred = Prediction(states[:, M:] + 0.01, torch.zeros_like(states[:, M:]))
    moved_future = states.clone()
    moved_future[:, M:, POS] += 1.0
    moved_last = states.clone()
    moved_last[:, M - 1, POS] += 1.0
    base = loss(pred, states, inputs, aux)
    assert loss(pred, moved_future, inputs, aux).physics.item() == pytest.approx(
        base.physics.item(), rel=1e-12
    )
    assert loss(pred, moved_last, inputs, aux).physics.item() > base.physics.item() + 1.0


def test_projection_zero_for_unit_quaternions_and_exact_otherwise():
    states, inputs, aux = truth_windows()
    x_hat = states[:, M:].clone()
    pred = Prediction(x_hat, torch.zeros_like(x_hat))
    assert loss(pred, states, inputs, aux).projection.item() == pytest.approx(0.0, abs=1e-20)
    x_hat[..., QUAT] *= 1.1  # |q| = 1.1 at every step
    expected = WEIGHTS.projection * N * 0.1**2
    assert loss(pred, states, inputs, aux).projection.item() == pytest.approx(expected, rel=1e-9)


def test_slack_that_cancels_the_mismatch_zeroes_the_physics_term():
    states, inputs, aux = truth_windows()
    g = torch.Generator().manual_seed(5)
    x_hat = states[:, M:] + 0.05 * torch.randn(states[:, M:].shape, generator=g, dtype=states.dtype)
    mismatch = physics_residual(
        x_hat, None, states[:, M - 1], inputs[:, M - 1 : -1], aux[:, M - 1 : -1], PARAMS
    )
    terms = loss(Prediction(x_hat, -mismatch), states, inputs, aux)
    assert terms.physics.item() == pytest.approx(0.0, abs=1e-20)
    decay = torch.exp(-WEIGHTS.beta * torch.arange(N, dtype=states.dtype))
    expected = WEIGHTS.slack * (mismatch.square().sum(-1) * decay).sum(-1).mean()
    assert terms.slack.item() == pytest.approx(expected.item(), rel=1e-12)
    assert terms.slack.item() > 0


def _imperfect_prediction(states):
    g = torch.Generator().manual_seed(7)
    noise = torch.randn(states[:, M:].shape, generator=g, dtype=states.dtype)
    x_hat = states[:, M:] + 0.05 * noise
    return Prediction(x_hat, 0.02 * noise.flip(-1))


@pytest.mark.parametrize(
    "field, term",
    [("physics", "physics"), ("projection", "projection"), ("slack", "slack")],
)
def test_each_weight_scales_its_term_linearly(field, term):
    states, inputs, aux = truth_windows()
    pred = _imperfect_prediction(states)
    base = loss(pred, states, inputs, aux)
    scaled = loss(pred, states, inputs, aux, weights=dataclasses.replace(WEIGHTS, **{field: 30.0}))
    factor = 30.0 / getattr(WEIGHTS, field)
    for name in ("fit", "physics", "projection", "slack"):
        want = getattr(base, name).item() * (factor if name == term else 1.0)
        assert getattr(scaled, name).item() == pytest.approx(want, rel=1e-12), name
    assert scaled.total.item() == pytest.approx(
        sum(getattr(scaled, k).item() for k in ("fit", "physics", "projection", "slack")),
        rel=1e-12,
    )


def test_fit_weights_scale_their_groups_linearly():
    states, inputs, aux = truth_windows()
    pred = _imperfect_prediction(states)
    names = ("position", "velocity", "quaternion", "load_position")
    only = {
        name: loss(
            pred,
            states,
            inputs,
            aux,
            weights=dataclasses.replace(WEIGHTS, **{k: (1.0 if k == name else 0.0) for k in names}),
        ).fit.item()
        for name in names
    }
    assert all(value > 0 for value in only.values())
    full = loss(pred, states, inputs, aux).fit.item()
    assert full == pytest.approx(sum(getattr(WEIGHTS, k) * only[k] for k in names), rel=1e-12)


@pytest.mark.parametrize("k", [0, 3])
def test_fit_horizon_weight_on_a_single_step_error(k):
    states, inputs, aux = truth_windows()
    x_hat = states[:, M:].clone()
    x_hat[:, k, 0] += 0.2  # 0.2 m position error at horizon step k only
    terms = loss(Prediction(x_hat, torch.zeros_like(x_hat)), states, inputs, aux)
    expected = WEIGHTS.position * 0.2**2 * math.exp(-WEIGHTS.alpha * k)
    assert terms.fit.item() == pytest.approx(expected, rel=1e-9)


def test_variants_switch_terms():
    states, inputs, aux = truth_windows()
    pred = _imperfect_prediction(states)
    no_slack_pred = Prediction(pred.states, None)
    proposed = loss(pred, states, inputs, aux, "proposed")
    no_slack = loss(no_slack_pred, states, inputs, aux, "no-slack")
    no_physics = loss(no_slack_pred, states, inputs, aux, "no-physics")
    assert proposed.physics > 0 and proposed.slack > 0
    assert no_slack.physics > 0 and no_slack.slack == 0
    assert no_physics.physics == 0 and no_physics.slack == 0
    for terms in (no_slack, no_physics):
        assert terms.fit.item() == pytest.approx(proposed.fit.item(), rel=1e-12)
        assert terms.projection.item() == pytest.approx(proposed.projection.item(), rel=1e-12)
    assert set(LOSS_VARIANTS) == {"proposed", "no-slack", "no-physics"}


def test_variant_and_model_must_agree():
    states, inputs, aux = truth_windows()
    pred = _imperfect_prediction(states)
    with pytest.raises(ValueError, match="slack=True"):
        loss(Prediction(pred.states, None), states, inputs, aux, "proposed")
    with pytest.raises(ValueError, match="slack=False"):
        loss(pred, states, inputs, aux, "no-physics")
    with pytest.raises(ValueError, match="unknown loss variant"):
        loss(pred, states, inputs, aux, "bogus")
    with pytest.raises(ValueError, match="states must be"):
        loss(pred, states[:, 1:], inputs, aux)
    base = ModelConfig(residual=True)
    assert model_config_for("proposed", base) == dataclasses.replace(base, slack=True)
    assert model_config_for("no-slack", base).slack is False
    assert model_config_for("no-physics", base).slack is False


def test_physics_term_gradcheck():
    states, inputs, aux = truth_windows(batch=2)
    n = 3
    g = torch.Generator().manual_seed(3)
    x_hat = states[:, M : M + n] + 0.05 * torch.randn(2, n, 13, generator=g, dtype=torch.float64)
    slack = 0.01 * torch.randn(2, n, 13, generator=g, dtype=torch.float64)
    x_hat.requires_grad_(True)
    slack.requires_grad_(True)

    def term(x, s):
        res = physics_residual(
            x, s, states[:, M - 1], inputs[:, M - 1 : M - 1 + n], aux[:, M - 1 : M - 1 + n], PARAMS
        )
        return physics_loss(res, WEIGHTS)

    assert torch.autograd.gradcheck(term, (x_hat, slack))


def test_gradients_flow_from_total_loss_to_every_parameter():
    states, inputs, aux = truth_windows(batch=4, dtype=torch.float32)
    torch.manual_seed(0)
    model = SlungLoadNet(model_config_for("proposed", ModelConfig()))
    model.fit_normalization(states, inputs)
    pred = model(states[:, :M], inputs[:, :M], inputs[:, M:])
    terms = loss(pred, states, inputs, aux)
    assert all(torch.isfinite(t) for t in terms)
    terms.total.backward()
    for name, p in model.named_parameters():
        assert p.grad is not None and p.grad.abs().max() > 0, name


# --- the "physics-relative" step weighting --------------------------------------------------


def test_physics_relative_scale_keeps_the_loss_of_physics_level_errors():
    # Errors whose square is exactly s_gn at every step (one group at a time): the scaled L_fit
    # equals the paper's, while each step's share becomes e^{-alpha n} / sum, not s_gn-heavy.
    g = torch.Generator().manual_seed(3)
    s = torch.rand(len(GROUPS), N, generator=g, dtype=torch.float64) * torch.logspace(-4, 0, N)
    scale = physics_relative_scale(s, WEIGHTS.alpha)
    truth = torch.zeros(1, N, 13, dtype=torch.float64)
    truth[..., QUAT.start] = 1.0
    for i, (name, sl) in enumerate(GROUPS.items()):
        pred = truth.clone()
        if sl == QUAT:  # q = (cos t/2, sin t/2, 0, 0): |q (x) 1^-1 - q_id|^2 = 2 - 2 cos t/2
            half = torch.acos(1.0 - s[i] / 2.0)
            pred[0, :, sl] = torch.stack([half.cos(), half.sin(), 0 * half, 0 * half], -1)
        else:
            pred[0, :, sl.start] = s[i].sqrt()
        paper = fit_loss(pred, truth, WEIGHTS)
        relative = fit_loss(pred, truth, WEIGHTS, scale)
        torch.testing.assert_close(relative, paper, rtol=1e-10, atol=0, msg=name)
        # Per step, the scaled squared error is c_g: the same at every step.
        torch.testing.assert_close(scale[i] * s[i], (scale[i] * s[i])[:1].expand(N))


def test_physics_relative_scale_of_a_flat_error_is_one_and_bad_shapes_are_refused():
    ones = physics_relative_scale(torch.full((len(GROUPS), N), 0.3), 0.1)
    torch.testing.assert_close(ones, torch.ones(len(GROUPS), N))
    with pytest.raises(ValueError, match=r"\(4, N\)"):
        physics_relative_scale(torch.ones(3, N), 0.1)


def test_step_weighting_and_fit_scale_must_agree():
    states, inputs, aux = truth_windows()
    pred = Prediction(states[:, M:] + 0.01, None)
    relative = dataclasses.replace(WEIGHTS, steps="physics-relative")
    scale = torch.ones(len(GROUPS), N, dtype=torch.float64)
    run = dict(history=M, params=PARAMS, variant="no-physics")
    with pytest.raises(ValueError, match="needs fit_scale"):
        compute_loss(pred, states, inputs, aux, weights=relative, **run)
    with pytest.raises(ValueError, match="takes no fit_scale"):
        compute_loss(pred, states, inputs, aux, weights=WEIGHTS, fit_scale=scale, **run)
    with pytest.raises(ValueError, match="fit_scale must be"):
        compute_loss(pred, states, inputs, aux, weights=relative, fit_scale=scale[:, 1:], **run)
    # A scale of ones is the paper's loss.
    a = compute_loss(pred, states, inputs, aux, weights=relative, fit_scale=scale, **run)
    b = compute_loss(pred, states, inputs, aux, weights=WEIGHTS, **run)
    torch.testing.assert_close(a.total, b.total)
    with pytest.raises(ValueError, match="unknown step weighting"):
        LossWeights(steps="late")


def test_mixed_step_weighting_is_the_mean_of_paper_and_physics_relative():
    s = torch.logspace(-5, -1, N, dtype=torch.float64).expand(len(GROUPS), N)
    relative = step_scale("physics-relative", s, 0.1)
    torch.testing.assert_close(relative, physics_relative_scale(s, 0.1))
    torch.testing.assert_close(step_scale("mixed", s, 0.1), 0.5 * (1.0 + relative))
    assert relative[0, 0] > 1.0 > relative[0, -1]  # the early steps gain weight, the late lose
    with pytest.raises(ValueError, match="no fit_scale"):
        step_scale("paper", s, 0.1)
