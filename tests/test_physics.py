"""The paper's discrete model against known behaviour: hover, free fall, pendulum, invariants."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from slungload import frames
from slungload.config import VehicleParams
from slungload.physics import (
    VehicleConstants,
    accelerations,
    hover_thrust,
    rollout,
    step,
    tension,
)
from slungload.state import (
    AUX_DIM,
    INPUT_DIM,
    LOAD_POS,
    POS,
    QUAT,
    STATE_DIM,
    VEL,
    quat_from_rotvec,
    quat_to_rotmat,
)

PARAMS = VehicleParams()


def hanging_state(angle: float = 0.0, dtype=torch.float64) -> torch.Tensor:
    """Vehicle at the origin, level; load on the cable, swung `angle` rad towards +x."""
    x = torch.zeros(STATE_DIM, dtype=dtype)
    x[QUAT] = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=dtype)
    x[LOAD_POS] = torch.tensor(
        [PARAMS.cable_length * math.sin(angle), 0.0, -PARAMS.cable_length * math.cos(angle)],
        dtype=dtype,
    )
    return x


def constant_input(thrust: float, n: int, rates=(0.0, 0.0, 0.0), dtype=torch.float64):
    u = torch.tensor([thrust, *rates], dtype=dtype)
    return u.expand(n, INPUT_DIM).clone()


def random_batch(batch: int, dtype=torch.float64, seed: int = 0):
    """States in the flight envelope: load near the cable sphere, tilted vehicle, moving."""
    g = torch.Generator().manual_seed(seed)
    x = torch.zeros(batch, STATE_DIM, dtype=dtype)
    x[:, POS] = torch.randn(batch, 3, generator=g, dtype=dtype)
    x[:, VEL] = torch.randn(batch, 3, generator=g, dtype=dtype)
    x[:, QUAT] = quat_from_rotvec(0.3 * torch.randn(batch, 3, generator=g, dtype=dtype))
    swing = torch.tensor([0.0, 0.0, -1.0], dtype=dtype) + 0.3 * torch.randn(
        batch, 3, generator=g, dtype=dtype
    )
    xi = swing / swing.norm(dim=-1, keepdim=True)
    x[:, LOAD_POS] = x[:, POS] + PARAMS.cable_length * xi
    u = torch.cat(
        [
            hover_thrust(PARAMS) * (1 + 0.2 * torch.rand(batch, 1, generator=g, dtype=dtype)),
            torch.randn(batch, 3, generator=g, dtype=dtype),
        ],
        dim=-1,
    )
    aux = 0.5 * torch.randn(batch, AUX_DIM, generator=g, dtype=dtype)
    return x, u, aux


def test_hover_equilibrium_stays_put():
    x0 = hanging_state()
    states, aux = rollout(
        x0,
        torch.zeros(AUX_DIM, dtype=torch.float64),
        constant_input(hover_thrust(PARAMS), 200),
        PARAMS,
    )
    assert torch.allclose(states, x0.expand_as(states), atol=1e-9)
    assert torch.allclose(aux, torch.zeros_like(aux), atol=1e-9)


def test_hover_tension_carries_the_load_weight():
    x0 = hanging_state()
    acc, acc_load, _ = accelerations(
        x0, constant_input(hover_thrust(PARAMS), 1)[0], torch.zeros(3, dtype=torch.float64), PARAMS
    )
    xi = (x0[LOAD_POS] - x0[POS]) / PARAMS.cable_length
    t_load = tension(
        xi,
        torch.tensor([0, 0, hover_thrust(PARAMS)], dtype=torch.float64),
        torch.zeros(3, dtype=torch.float64),
        PARAMS,
    )
    assert t_load.item() == pytest.approx(PARAMS.mass_load * PARAMS.gravity, rel=1e-12)
    assert torch.allclose(acc, torch.zeros(3, dtype=torch.float64), atol=1e-12)
    assert torch.allclose(acc_load, torch.zeros(3, dtype=torch.float64), atol=1e-12)


def test_zero_thrust_falls_at_g():
    n = 20
    x0 = hanging_state()
    states, _ = rollout(
        x0, torch.zeros(AUX_DIM, dtype=torch.float64), constant_input(0.0, n), PARAMS
    )
    t = PARAMS.dt * torch.arange(1, n + 1, dtype=torch.float64)
    expected_z = -0.5 * PARAMS.gravity * t**2
    # Without thrust the tension vanishes: both bodies fall freely, cable unchanged.
    assert torch.allclose(states[:, 2], expected_z, atol=1e-12)
    assert torch.allclose(states[:, 5], -PARAMS.gravity * t, atol=1e-12)
    assert torch.allclose(states[:, 12], x0[12] + expected_z, atol=1e-12)


def test_thrust_along_body_axis_accelerates_that_way():
    # Rolled +30 deg about x: body z points towards -y in the world.
    x0 = hanging_state()
    x0[QUAT] = quat_from_rotvec(torch.tensor([math.radians(30), 0.0, 0.0], dtype=torch.float64))
    acc, _, _ = accelerations(
        x0, constant_input(10.0, 1)[0], torch.zeros(3, dtype=torch.float64), PARAMS
    )
    assert acc[1] < 0
    assert acc[0] == pytest.approx(0.0, abs=1e-12)


def test_small_swing_has_pendulum_period():
    angle = math.radians(3)
    n = 400
    states, _ = rollout(
        hanging_state(angle),
        torch.zeros(AUX_DIM, dtype=torch.float64),
        constant_input(hover_thrust(PARAMS), n),
        PARAMS,
    )
    rel_x = (states[:, 10] - states[:, 0]).numpy()
    crossings = np.where((rel_x[:-1] < 0) & (rel_x[1:] >= 0))[0]
    periods = np.diff(crossings) * PARAMS.dt
    assert len(periods) >= 4
    # A free vehicle moves against the load: the coupled period is shorter by
    # sqrt(mQ / (mQ + mL)) than the fixed-pivot 2 pi sqrt(l / g).
    fixed = 2 * math.pi * math.sqrt(PARAMS.cable_length / PARAMS.gravity)
    coupled = fixed * math.sqrt(PARAMS.mass_quad / (PARAMS.mass_quad + PARAMS.mass_load))
    assert np.mean(periods) == pytest.approx(coupled, rel=0.03)
    assert np.mean(periods) == pytest.approx(fixed, rel=0.06)
    # The cable length stays close to l along the swing (the model has no constraint).
    length = (states[:, LOAD_POS] - states[:, POS]).norm(dim=-1)
    assert torch.all((length - PARAMS.cable_length).abs() < 0.02)


def test_load_rate_follows_damped_recursion_without_thrust():
    aux0 = torch.tensor([0, 0, 0, 0.4, -0.2, 0.1], dtype=torch.float64)
    _, aux = rollout(hanging_state(0.2), aux0, constant_input(0.0, 10), PARAMS)
    decay = (1 - PARAMS.load_damping) ** torch.arange(1, 11, dtype=torch.float64)
    assert torch.allclose(aux[:, 3:], decay[:, None] * aux0[3:], atol=1e-12)


def test_body_rates_rotate_the_attitude():
    rate = 0.5  # rad/s about body z
    n = 40
    states, _ = rollout(
        hanging_state(),
        torch.zeros(AUX_DIM, dtype=torch.float64),
        constant_input(hover_thrust(PARAMS), n, rates=(0, 0, rate)),
        PARAMS,
    )
    yaw = 2 * torch.atan2(states[-1, 9], states[-1, 6])
    assert yaw.item() == pytest.approx(rate * n * PARAMS.dt, rel=1e-9)


def test_quaternions_stay_unit():
    x, u, aux = random_batch(64)
    inputs = u[:, None, :].expand(64, 50, 4) + 0.5 * torch.randn(64, 50, 4, dtype=torch.float64)
    states, _ = rollout(x, aux, inputs, PARAMS)
    assert torch.allclose(
        states[..., QUAT].norm(dim=-1), torch.ones(64, 50, dtype=torch.float64), atol=1e-12
    )


def test_batched_equals_looped():
    x, u, aux = random_batch(8)
    xb, ab = step(x, u, aux, PARAMS)
    for i in range(8):
        xi, ai = step(x[i], u[i], aux[i], PARAMS)
        assert torch.allclose(xb[i], xi, atol=1e-14)
        assert torch.allclose(ab[i], ai, atol=1e-14)
    # Extra leading dimensions broadcast the same way.
    x4, a4 = step(x.view(2, 4, -1), u.view(2, 4, -1), aux.view(2, 4, -1), PARAMS)
    assert torch.allclose(x4.reshape(8, -1), xb)
    assert torch.allclose(a4.reshape(8, -1), ab)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_dtype_is_preserved(dtype):
    x, u, aux = random_batch(4, dtype=dtype)
    xn, an = step(x, u, aux, PARAMS)
    assert xn.dtype == dtype and an.dtype == dtype
    x64, a64 = step(*(t.double() for t in (x, u, aux)), PARAMS)
    assert torch.allclose(xn.double(), x64, atol=1e-5 if dtype == torch.float32 else 1e-14)


def test_rotation_matrix_matches_quaternion_convention():
    # w-x-y-z quaternion of +90 deg about z maps body x to world y.
    q = torch.tensor([math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)], dtype=torch.float64)
    r = quat_to_rotmat(q)
    assert torch.allclose(
        r @ torch.tensor([1.0, 0, 0], dtype=torch.float64),
        torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64),
        atol=1e-12,
    )


def test_the_numpy_rotation_matrix_is_the_torch_one():
    # frames.rotation_matrix (numpy: the MPC, the oracle) and quat_to_rotmat (torch: physics)
    q = torch.nn.functional.normalize(torch.randn(16, 4, dtype=torch.float64), dim=-1)
    np.testing.assert_allclose(frames.rotation_matrix(q.numpy()), quat_to_rotmat(q).numpy(),
                               atol=1e-14)  # fmt: skip
    c, s = math.cos(0.3), math.sin(0.3)  # a yaw of 0.3 rad is a rotation about z
    yaw = np.array([math.cos(0.15), 0.0, 0.0, math.sin(0.15)])
    np.testing.assert_allclose(frames.rotation_matrix(yaw), [[c, -s, 0], [s, c, 0], [0, 0, 1]],
                               atol=1e-15)  # fmt: skip


def test_gradcheck_float64():
    x, u, aux = random_batch(3)
    inputs = (x.requires_grad_(), u.requires_grad_(), aux.requires_grad_())
    assert torch.autograd.gradcheck(lambda a, b, c: step(a, b, c, PARAMS), inputs)


def test_params_validate():
    with pytest.raises(ValueError, match="cable_length"):
        VehicleParams(cable_length=0.0)
    with pytest.raises(ValueError, match="load_damping"):
        VehicleParams(load_damping=1.5)


def test_model_is_equivariant_under_a_turn_about_z():
    from slungload.state import rotate_about_z

    x, u, aux = random_batch(16)
    yaw = torch.linspace(-3.0, 3.0, 16, dtype=torch.float64)
    x_next, aux_next = step(x, u, aux, PARAMS)
    xr, auxr = rotate_about_z(x, aux, yaw)
    xr_next, auxr_next = step(xr, u, auxr, PARAMS)  # inputs live in the body frame: unchanged
    expected_x, expected_aux = rotate_about_z(x_next, aux_next, yaw)
    assert torch.allclose(xr_next, expected_x, atol=1e-12)
    assert torch.allclose(auxr_next, expected_aux, atol=1e-12)
    # A turn by 2 pi is the identity on positions and velocities, -q on the attitude.
    full, _ = rotate_about_z(x, aux, torch.tensor(2 * math.pi, dtype=torch.float64))
    assert torch.allclose(full[:, POS], x[:, POS], atol=1e-12)
    assert torch.allclose(full[:, QUAT], -x[:, QUAT], atol=1e-12)


# --- the constants' tensor view: one set per dataset, one set per window ----------------------

# Constants other than the defaults, every field changed.
OTHER_PARAMS = VehicleParams(
    mass_quad=1.5, mass_load=0.15, cable_length=0.85, load_damping=0.05, dt=0.025,
    gravity=9.8, thrust_gain=1.12,
)  # fmt: skip


def test_vehicle_constants_mirror_vehicle_params():
    # Every field of VehicleParams, in its order: a new constant reaches the tensor view.
    assert VehicleConstants._fields == tuple(f.name for f in dataclasses.fields(VehicleParams))
    constants = VehicleConstants.of(OTHER_PARAMS)
    assert constants._asdict() == dataclasses.asdict(OTHER_PARAMS)
    assert all(type(value) is float for value in constants)


def test_one_set_of_floats_is_the_same_arithmetic_as_vehicle_params():
    x, u, aux = random_batch(16)
    inputs = u[:, None, :] + 0.3 * torch.randn(16, 20, 4, dtype=torch.float64)
    for params in (PARAMS, OTHER_PARAMS):
        want = rollout(x, aux, inputs, params)
        got = rollout(x, aux, inputs, VehicleConstants.of(params))
        for a, b in zip(got, want, strict=True):
            assert torch.equal(a, b)


def test_per_window_constants_equal_each_window_alone():
    """A batch rolled out with one set of constants per window equals each window rolled out
    alone with its own VehicleParams."""
    batch = 6
    x, u, aux = random_batch(batch)
    inputs = u[:, None, :] + 0.3 * torch.randn(batch, 20, 4, dtype=torch.float64)
    params = [
        dataclasses.replace(
            OTHER_PARAMS if i % 2 else PARAMS,
            mass_load=0.05 + 0.03 * i,
            cable_length=0.5 + 0.1 * i,
            load_damping=0.01 * i,
        )
        for i in range(batch)
    ]
    constants = VehicleConstants.stack(params, dtype=torch.float64)
    assert all(c.shape == (batch,) and c.dtype == torch.float64 for c in constants)
    states, auxes = rollout(x, aux, inputs, constants)
    for i, p in enumerate(params):
        want_states, want_aux = rollout(x[i : i + 1], aux[i : i + 1], inputs[i : i + 1], p)
        torch.testing.assert_close(states[i : i + 1], want_states, rtol=0.0, atol=1e-12)
        torch.testing.assert_close(auxes[i : i + 1], want_aux, rtol=0.0, atol=1e-12)
    # The windows do differ: the constants reached each row.
    alone, _ = rollout(x, aux, inputs, PARAMS)
    assert not torch.allclose(states[1:], alone[1:])


def test_per_window_constants_broadcast_over_more_leading_dimensions():
    # Windows (B,) each with K candidate input sequences: constants of shape (B, 1).
    x, u, aux = random_batch(6)
    params = [PARAMS, OTHER_PARAMS, PARAMS]
    per_window = VehicleConstants.stack(params, dtype=torch.float64)
    per_row = VehicleConstants(*(c[:, None] for c in per_window))
    got, _ = step(x.view(3, 2, -1), u.view(3, 2, -1), aux.view(3, 2, -1), per_row)
    for b, p in enumerate(params):
        want, _ = step(x.view(3, 2, -1)[b], u.view(3, 2, -1)[b], aux.view(3, 2, -1)[b], p)
        torch.testing.assert_close(got[b], want, rtol=0.0, atol=1e-12)


def test_per_window_constants_keep_gradients_and_dtype():
    x, u, aux = random_batch(3, dtype=torch.float32)
    constants = VehicleConstants.stack([PARAMS, OTHER_PARAMS, PARAMS], dtype=torch.float32)
    x_next, aux_next = step(x, u, aux, constants)
    assert x_next.dtype == torch.float32 and aux_next.dtype == torch.float32
    x, u, aux = random_batch(3)
    lengths = torch.tensor([0.6, 0.7, 0.8], dtype=torch.float64, requires_grad=True)
    stacked = VehicleConstants.stack([PARAMS] * 3, dtype=torch.float64)
    x_next, _ = step(x, u, aux, stacked._replace(cable_length=lengths))
    x_next[:, POS].sum().backward()
    assert lengths.grad is not None and (lengths.grad != 0).all()
    with pytest.raises(ValueError, match="at least one"):
        VehicleConstants.stack([])
