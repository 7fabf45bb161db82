"""The prediction-model contract (models/prediction.py): the physics model and every registered
network, each with two entry points, windows (evaluation) and candidates (control), that agree.
"""

from __future__ import annotations

from dataclasses import asdict, replace
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from flights import TINY

from slungload import physics
from slungload.config import VehicleParams, WindowConfig
from slungload.data.windows import Windows, physics_rollout
from slungload.load_state import estimate_load_state
from slungload.models import MODELS, build
from slungload.models.prediction import (
    PHYSICS,
    NetworkModel,
    PhysicsModel,
    PredictionModel,
    load_prediction_model,
)
from slungload.state import QUAT

PARAMS = VehicleParams()
HOVER_T = (PARAMS.mass_quad + PARAMS.mass_load) * PARAMS.gravity
M, N, K = 6, 5, 7


def hover_state(p=(0.0, 0.0, 1.5)) -> np.ndarray:
    p = np.asarray(p, dtype=float)
    return np.concatenate([p, np.zeros(3), [1.0, 0, 0, 0], p - [0, 0, PARAMS.cable_length]])


def random_history(m: int, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """x_hist (m, 13) near hover with unit quaternions, u_past (m - 1, 4), float64."""
    x = torch.from_numpy(np.tile(hover_state(), (m, 1)))
    x = x + 0.01 * torch.randn(x.shape, generator=gen, dtype=torch.float64)
    x[:, QUAT] = x[:, QUAT] / x[:, QUAT].norm(dim=-1, keepdim=True)
    u = torch.tensor([HOVER_T, 0, 0, 0], dtype=torch.float64).repeat(m - 1, 1)
    return x, u + 0.1 * torch.randn(u.shape, generator=gen, dtype=torch.float64)


def random_plans(k: int, n: int, gen: torch.Generator, scale: float = 0.5) -> torch.Tensor:
    hover = torch.tensor([HOVER_T, 0, 0, 0], dtype=torch.float64)
    return hover + scale * torch.randn(k, n, 4, generator=gen, dtype=torch.float64)


def candidate_windows(x_hist: torch.Tensor, u_past: torch.Tensor, plans: torch.Tensor) -> Windows:
    """The K windows that ``predict_candidates(x_hist, u_past, plans)`` stands for (float64):
    history x_hist with inputs [u_past; u_k], future inputs the rest of the plan (its last row
    repeated: a window's last input is never used); the future states are not read (NaN)."""
    k, n = plans.shape[:2]
    m = x_hist.shape[0]
    states = torch.full((k, m + n, 13), float("nan"), dtype=torch.float64)
    states[:, :m] = x_hist
    inputs = torch.cat([u_past.expand(k, m - 1, 4), plans, plans[:, -1:]], dim=1)
    aux = torch.zeros(k, m + n, 6, dtype=torch.float64)
    aux[:, :m] = estimate_load_state(x_hist, PARAMS)  # causal: step M-1 uses M-2 and M-1
    return Windows(
        states=states,
        inputs=inputs,
        aux=aux,
        flight=torch.zeros(k, dtype=torch.int64),
        start=torch.zeros(k, dtype=torch.int64),
        names=("candidates",),
        window=WindowConfig(history=m, horizon=n),
    )


def network(architecture: str) -> torch.nn.Module:
    torch.manual_seed(0)
    return build(replace(TINY, architecture=architecture), PARAMS).double().eval()


# --- the contract --------------------------------------------------------------------------


@pytest.mark.parametrize("architecture", sorted(MODELS))
def test_both_implementations_meet_the_protocol(architecture):
    for model in (PhysicsModel(PARAMS), NetworkModel(network(architecture), M)):
        assert isinstance(model, PredictionModel)
        assert isinstance(model.name, str) and model.history >= 2
    assert isinstance(load_prediction_model(PHYSICS, PARAMS), PhysicsModel)
    assert not isinstance(object(), PredictionModel)


def test_physics_candidates_equal_windows_sharing_the_history():
    gen = torch.Generator().manual_seed(0)
    x_hist, u_past = random_history(M, gen)
    plans = random_plans(K, N, gen)
    model = PhysicsModel(PARAMS)
    got = model.predict_candidates(x_hist, u_past, plans)
    want = model.predict_windows(candidate_windows(x_hist, u_past, plans))
    assert got.shape == want.shape == (K, N, 13) and want.dtype == torch.float64
    torch.testing.assert_close(got, want, rtol=0, atol=1e-12)


@pytest.mark.parametrize("architecture", sorted(MODELS))
def test_network_candidates_equal_windows_sharing_the_history(architecture):
    # forward_candidates runs the encoder once over the M - 1 shared rows; predict_windows runs
    # forward over K windows. Same predictions (windows give float32, as evaluation compares).
    gen = torch.Generator().manual_seed(1)
    x_hist, u_past = random_history(M, gen)
    plans = random_plans(K, N, gen, scale=1.0)
    model = NetworkModel(network(architecture), M, batch_size=3)  # 3 batches of windows
    got = model.predict_candidates(x_hist, u_past, plans)
    want = model.predict_windows(candidate_windows(x_hist, u_past, plans))
    assert got.dtype == torch.float64 and want.dtype == torch.float32
    torch.testing.assert_close(got.float(), want, rtol=0, atol=1e-6)
    torch.testing.assert_close(got[:, :, QUAT].norm(dim=-1), torch.ones(K, N, dtype=torch.float64))


def test_physics_candidates_are_the_rollout_from_the_causal_load_estimate():
    gen = torch.Generator().manual_seed(0)
    x_hist, u_past = random_history(5, gen)
    plans = random_plans(7, 12, gen)
    got = load_prediction_model("physics").predict_candidates(x_hist, u_past, plans)
    aux = estimate_load_state(x_hist, PARAMS)[-1]
    want, _ = physics.rollout(x_hist[-1].expand(7, 13), aux.expand(7, 6), plans, PARAMS)
    assert got.shape == (7, 12, 13)
    torch.testing.assert_close(got, want, rtol=0, atol=1e-12)


@pytest.mark.parametrize("architecture", sorted(MODELS))
def test_network_candidates_are_forward_with_the_candidate_as_the_last_history_input(
    architecture,
):
    # Every registered architecture plugs in through forward_candidates, which runs the encoder
    # once over the shared rows: it must equal forward per candidate, where the candidate u_k
    # pairs with x_k (the history's last input row) and the predictions are x_{k+1} ... x_{k+N}.
    net = network(architecture)
    gen = torch.Generator().manual_seed(1)
    x_hist, u_past = random_history(6, gen)
    plans = random_plans(5, 4, gen, scale=1.0)
    got = NetworkModel(net, 6).predict_candidates(x_hist, u_past, plans)
    for i in range(5):
        u_hist = torch.cat([u_past, plans[i, :1]])[None]
        u_future = torch.cat([plans[i, 1:], torch.zeros(1, 4, dtype=torch.float64)])[None]
        want = net(x_hist[None], u_hist, u_future).states[0]  # its last input is unused
        want[:, QUAT] = want[:, QUAT] / want[:, QUAT].norm(dim=-1, keepdim=True)
        torch.testing.assert_close(got[i], want, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize(
    ("x_shape", "u_shape", "plan_shape"),
    [((1, 13), (0, 4), (3, 5, 4)), ((4, 13), (4, 4), (3, 5, 4)), ((4, 13), (3, 4), (5, 4))],
)
def test_candidates_of_the_wrong_shape_are_refused(x_shape, u_shape, plan_shape):
    args = (torch.zeros(x_shape), torch.zeros(u_shape), torch.zeros(plan_shape))
    for model in (PhysicsModel(PARAMS), NetworkModel(network("lstm-attention"), 4)):
        with pytest.raises(ValueError, match=r"predict_candidates: expected x_hist"):
            model.predict_candidates(*args)


# --- the one physics-only rollout over windows ---------------------------------------------


def test_physics_rollout_in_batches_equals_one_batch_and_carries_gradients():
    gen = torch.Generator().manual_seed(2)
    x_hist, u_past = random_history(M, gen)
    windows = candidate_windows(x_hist, u_past, random_plans(K, N, gen))
    whole = physics_rollout(windows, PARAMS, batch_size=None)
    torch.testing.assert_close(physics_rollout(windows, PARAMS, batch_size=3), whole)
    # Any object with VehicleParams' attributes, some of them tensors (as identify fits them):
    # the rollout is differentiable in them.
    length = torch.tensor(PARAMS.cable_length, dtype=torch.float64, requires_grad=True)
    constants = SimpleNamespace(**{**asdict(PARAMS), "cable_length": length})
    out = physics_rollout(windows, constants, batch_size=None)
    out[..., 10:13].sum().backward()
    assert length.grad is not None and torch.isfinite(length.grad)
