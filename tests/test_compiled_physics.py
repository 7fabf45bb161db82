"""The compiled copy of the discrete model and the load-state estimates
(``deploy/compiled/physics.py``) against the torch originals it copies: ``physics.step`` for
one state and for candidates in columns, ``load_state.estimate_load_state`` and
``load_state.fit_load_state``. A change to ``physics.py`` or ``load_state.py`` that is not made
in the copy fails here."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from slungload import physics
from slungload.config import VehicleParams
from slungload.deploy.compiled import physics as compiled
from slungload.load_state import estimate_load_state, fit_load_state
from slungload.physics import VehicleConstants
from slungload.state import LOAD_POS, POS, QUAT, RATES, STATE_DIM, THRUST

# Constants other than the defaults, each of those f reads changed.
OTHER_PARAMS = VehicleParams(
    mass_quad=1.5, mass_load=0.15, cable_length=0.85, load_damping=0.05, dt=0.025,
    gravity=9.8, thrust_gain=1.12,
)  # fmt: skip
PARAMS = [VehicleParams(), OTHER_PARAMS]
THRUST_COL = STATE_DIM + THRUST.start
RATE_COLS = slice(STATE_DIM + RATES.start, STATE_DIM + RATES.stop)


def random_steps(count: int, dtype, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``count`` random batch-1 arguments of ``physics.step``: rows (count, 17) = (x, u) in the
    package layout with quaternions of norm 0.5 ... 1.5 (a corrected decoder state need not be
    unit), thrust around hover, and load states aux (count, 6)."""
    rng = np.random.default_rng(seed)
    xu = rng.normal(size=(count, STATE_DIM + 4))
    xu[:, LOAD_POS] = xu[:, POS] + 0.7 * rng.normal(size=(count, 3)) / np.sqrt(3)
    xu[:, QUAT] *= rng.uniform(0.5, 1.5, (count, 1)) / np.linalg.norm(xu[:, QUAT], axis=1)[:, None]
    xu[:, THRUST_COL] = 14.5 + 3.0 * rng.normal(size=count)
    xu[:, RATE_COLS] *= 3.0  # rad/s
    xu[:3, RATE_COLS] = [[0.0, 0.0, 0.0], [1e-5, 0.0, -2e-5], [0.0, 3e-3, 0.0]]  # near zero
    return xu.astype(dtype), rng.normal(size=(count, 6)).astype(dtype)


@pytest.mark.parametrize("params", PARAMS, ids=["default", "other"])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_physics_step_is_physics_step(params: VehicleParams, dtype):
    """``physics_step`` (Numba, one state: the batch-1 predictor's) equals ``physics.step``
    (torch, batched), the one written definition of the model: to round-off in float64, to
    float32 precision in float32."""
    xu, aux = random_steps(300, dtype)
    want_x, want_aux = physics.step(
        torch.from_numpy(xu[:, :STATE_DIM]), torch.from_numpy(xu[:, STATE_DIM:]),
        torch.from_numpy(aux), params,
    )  # fmt: skip
    constants = VehicleConstants.of(params)
    got_x, got_aux = np.empty((len(xu), STATE_DIM), dtype), np.empty((len(xu), 6), dtype)
    for i in range(len(xu)):
        compiled.physics_step(xu[i], aux[i], constants, got_x[i], got_aux[i])
    rtol, atol = (1e-12, 1e-12) if dtype == np.float64 else (1e-5, 1e-5)
    np.testing.assert_allclose(got_x, want_x.numpy(), rtol=rtol, atol=atol)
    np.testing.assert_allclose(got_aux, want_aux.numpy(), rtol=rtol, atol=atol)


@pytest.mark.parametrize("params", PARAMS, ids=["default", "other"])
def test_physics_step_in_columns_is_physics_step(params):
    """``physics_step_columns`` (the batched backend's) equals ``physics.step`` to 1e-12 with
    body rates up to 80 rad/s (half angles beyond 1 rad take the C library's sin and cos, the
    others the polynomials), and the one-state step bit for bit (one body serves both)."""
    gen = torch.Generator().manual_seed(6)
    k = 64
    x = torch.randn(k, STATE_DIM, generator=gen, dtype=torch.float64)
    x[:, QUAT] += torch.tensor([2.0, 0, 0, 0])  # any norm: the step normalises
    u = torch.randn(k, 4, generator=gen, dtype=torch.float64) * torch.tensor([5.0, 20, 20, 20])
    u[:4, 1:] *= 4.0
    aux = torch.randn(k, 6, generator=gen, dtype=torch.float64)
    want_x, want_aux = physics.step(x, u, aux, params)
    constants = VehicleConstants.of(params)
    got_x, got_aux = np.empty((STATE_DIM, k)), np.empty((6, k))
    xu = np.ascontiguousarray(torch.cat([x, u], 1).T.numpy())
    aux_cols = np.ascontiguousarray(aux.T.numpy())
    compiled.physics_step_columns(xu, aux_cols, constants, np.empty((4, k)), got_x, got_aux)
    np.testing.assert_allclose(got_x.T, want_x.numpy(), rtol=0, atol=1e-12)
    np.testing.assert_allclose(got_aux.T, want_aux.numpy(), rtol=0, atol=1e-12)
    one_x, one_aux = np.empty(STATE_DIM), np.empty(6)
    for r in range(k):
        compiled.physics_step(xu[:, r].copy(), aux_cols[:, r].copy(), constants, one_x, one_aux)
        np.testing.assert_array_equal(one_x, got_x[:, r])
        np.testing.assert_array_equal(one_aux, got_aux[:, r])


@pytest.mark.parametrize("params", PARAMS, ids=["default", "other"])
def test_physics_rollout_is_physics_rollout(params):
    gen = torch.Generator().manual_seed(7)
    xu, aux = random_steps(4, np.float64, seed=3)
    x0, aux0 = torch.from_numpy(xu[-1, :STATE_DIM]), torch.from_numpy(aux[-1])
    plans = torch.tensor([14.5, 0, 0, 0]) + torch.randn(5, 30, 4, generator=gen).double()
    want, _ = physics.rollout(x0.expand(5, -1), aux0.expand(5, -1), plans, params)
    got = np.empty((5, 30, STATE_DIM))
    constants = VehicleConstants.of(params)
    compiled.physics_rollout(x0.numpy(), aux0.numpy(), plans.numpy(), constants, got)
    np.testing.assert_allclose(got, want.numpy(), rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_load_state_estimate_is_estimate_load_state(dtype):
    xu, _ = random_steps(200, dtype, seed=1)
    pairs = xu[:, :STATE_DIM].reshape(100, 2, STATE_DIM)  # (prev, last)
    want = estimate_load_state(torch.from_numpy(pairs), OTHER_PARAMS)[:, -1].numpy()
    constants = VehicleConstants.of(OTHER_PARAMS)
    got = np.empty((len(pairs), 6), dtype)
    for i, (prev, last) in enumerate(pairs):
        compiled.estimate_load_state(prev, last, constants, got[i])
    rtol, atol = (1e-12, 1e-12) if dtype == np.float64 else (1e-5, 1e-5)
    np.testing.assert_allclose(got, want, rtol=rtol, atol=atol)


@pytest.mark.parametrize("rows", [50, 9, 5, 3])
def test_smoothed_load_state_is_fit_load_state(rows: int):
    xu, _ = random_steps(20 * rows, np.float64, seed=2)
    windows = xu[:, :STATE_DIM].reshape(20, rows, STATE_DIM)
    filters = compiled.load_filters("smoothed", OTHER_PARAMS.dt)
    want = fit_load_state(torch.from_numpy(windows[:, -min(rows, 9) :]), OTHER_PARAMS).numpy()
    got = np.empty((len(windows), 6))
    for i, window in enumerate(windows):
        compiled.fit_load_state(window, rows, filters, VehicleConstants.of(OTHER_PARAMS), got[i])
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)
    assert compiled.load_filters("difference", OTHER_PARAMS.dt).shape == (0, 0)


def test_vehicle_constants_reach_the_compiled_copy_as_floats():
    # The copy reads VehicleConstants' fields by name (physics.VehicleConstants mirrors every
    # VehicleParams field, test_physics), as python floats, which Numba types as float64.
    constants = VehicleConstants.of(OTHER_PARAMS)
    assert constants._asdict() == dataclasses.asdict(OTHER_PARAMS)
    assert all(type(value) is float for value in constants)


@pytest.mark.parametrize("params", PARAMS, ids=["default", "other"])
def test_adapted_constants_is_adapted(physics_flight, params):
    """The numpy copy of a window's constants (``adapted_constants``, the compiled paths') is
    ``constants_estimate.adapted``, the torch original, on swinging windows and on a still one
    (where the prior and the clipping decide)."""
    from slungload.constants_estimate import adapted

    flight = physics_flight("a", 3, 80)
    windows = [flight.states[i : i + 50] for i in (0, 15, 30)]
    still = np.repeat(flight.states[:1], 50, axis=0)
    for states, thrust in [(s, flight.inputs[:50, 0]) for s in windows] + [
        (still, np.full(50, 14.0))
    ]:
        want = adapted(
            torch.from_numpy(states)[None],
            torch.from_numpy(np.stack([thrust] * 4, -1))[None],
            params,
        )
        got = compiled.adapted_constants(states, thrust, VehicleConstants.of(params))
        assert got.mass_load == pytest.approx(float(want.mass_load[0]), rel=1e-9)
        assert got.cable_length == pytest.approx(float(want.cable_length[0]), rel=1e-12)
        assert got._replace(mass_load=0.0, cable_length=0.0) == VehicleConstants.of(
            params
        )._replace(mass_load=0.0, cable_length=0.0)
