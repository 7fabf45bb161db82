"""Fitted physical constants: positivity by construction, the identity at the start, and the
identification check (simulated flights without unmodelled effects, constants 30 % off)."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from slungload.config import VehicleParams
from slungload.models.constants import FITTED, LearnedConstants
from slungload.physics import VehicleConstants, step
from slungload.sim import Effects, SimConfig, simulate_dataset
from slungload.sim.dataset import vehicle_params
from slungload.training.identify import identify


def test_untrained_constants_are_the_initial_ones():
    initial = VehicleParams(mass_load=0.2, cable_length=0.9, load_damping=0.04, thrust_gain=1.1)
    constants = LearnedConstants(initial)
    start = constants.params()
    for field in dataclasses.fields(VehicleParams):  # to rounding (the damping's logit)
        assert getattr(start, field.name) == pytest.approx(getattr(initial, field.name), 1e-14)
    x = torch.randn(3, 13, dtype=torch.float64)
    u, aux = torch.randn(3, 4, dtype=torch.float64), torch.randn(3, 6, dtype=torch.float64)
    for a, b in zip(step(x, u, aux, constants.current()), step(x, u, aux, initial), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)


def test_current_constants_are_the_physics_tensor_view():
    # The fitted constants are 0-d float64 tensors (differentiable), the others stay the
    # initial python floats, so the physics reads them as it reads VehicleParams.
    initial = VehicleParams(mass_load=0.2, cable_length=0.9)
    now = LearnedConstants(initial, ("cable_length", "thrust_gain")).current()
    assert isinstance(now, VehicleConstants)
    assert now.cable_length.shape == () and now.cable_length.requires_grad
    assert now.thrust_gain.shape == () and now.thrust_gain.dtype == torch.float64
    for name in ("mass_quad", "mass_load", "load_damping", "dt", "gravity"):
        assert type(getattr(now, name)) is float and getattr(now, name) == getattr(initial, name)


def test_constants_stay_physical_whatever_the_parameters():
    constants = LearnedConstants(VehicleParams())
    with torch.no_grad():
        constants.theta.copy_(torch.tensor([-40.0, 40.0, -40.0, 40.0], dtype=torch.float64))
    with torch.no_grad():
        now = constants.current()
    assert min(float(now.mass_load), float(now.cable_length), float(now.thrust_gain)) > 0
    assert 0 < float(now.load_damping) <= 1


def test_gradients_reach_every_fitted_constant():
    constants = LearnedConstants(VehicleParams())
    x = torch.randn(4, 13, dtype=torch.float64)
    x[:, 6:10] = torch.nn.functional.normalize(x[:, 6:10], dim=-1)
    x[:, 10:13] = x[:, 0:3] + torch.tensor([0.1, 0.0, -0.68], dtype=torch.float64)
    u = torch.tensor([[15.0, 0.1, -0.2, 0.0]] * 4, dtype=torch.float64)
    aux = torch.randn(4, 6, dtype=torch.float64)
    x_next, aux_next = step(x, u, aux, constants.current())
    (x_next.square().sum() + aux_next.square().sum()).backward()
    assert constants.theta.grad is not None and (constants.theta.grad.abs() > 0).all()


def test_fitting_only_some_constants_and_bad_requests():
    constants = LearnedConstants(VehicleParams(), ("cable_length",))
    assert constants.fitted == ("cable_length",) and constants.theta.shape == (1,)
    with pytest.raises(ValueError, match="cannot fit"):
        LearnedConstants(VehicleParams(), ("mass_quad",))
    assert set(FITTED) == {"mass_load", "cable_length", "load_damping", "thrust_gain"}


@pytest.mark.slow
def test_constants_30_percent_off_are_identified_within_5_percent(tmp_path):
    # Without unmodelled effects the simulator differs from the discrete model only in its
    # elastic cable and continuous time: the fit must find the simulator's own constants.
    config = SimConfig(effects=Effects().without(*Effects.names()))
    data = tmp_path / "clean"
    simulate_dataset(data, flights=6, seed=1, config=config, workers=1, progress=False)
    truth = vehicle_params(config)
    off = dataclasses.replace(
        truth,
        mass_load=1.3 * truth.mass_load,
        cable_length=0.7 * truth.cable_length,
        load_damping=1.3 * truth.load_damping,
        thrust_gain=1.3,
    )
    found = identify(data, params=off, max_windows=2048)
    assert found.train_error[1] < 0.01 * found.train_error[0]
    assert found.val_error[1] < 0.01 * found.val_error[0]
    for name, value in (("mass_load", truth.mass_load), ("cable_length", truth.cable_length),
                        ("thrust_gain", 1.0)):  # fmt: skip
        assert getattr(found.params, name) == pytest.approx(value, rel=0.05), name
    assert found.params.mass_quad == truth.mass_quad  # not fitted: mQ and k_T trade off
