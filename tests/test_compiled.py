"""The Numba batch-1 predictor (``deploy/compiled/predictor.py``): its predictions against the
eager network for every model mode and both compiled architectures, and what it refuses. Its
kernels are tested in ``test_compiled_kernels.py``, its copy of the discrete model in
``test_compiled_physics.py``."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from flights import predict_args

from slungload import physics
from slungload.config import ModelConfig, VehicleParams, WindowConfig
from slungload.data.windows import make_windows
from slungload.deploy.compiled import (
    COMPILED_ARCHITECTURES,
    PARITY_TOLERANCE,
    CompiledPredictor,
    unsupported,
)
from slungload.deploy.compiled.fold import fold
from slungload.deploy.compiled.weights import PHYSICS_STEP as PHYSICS_STEP_MODE
from slungload.deploy.predictor import Predictor
from slungload.load_state import estimate_load_state
from slungload.models import MODELS, PhysicsStepNet, build
from slungload.models.lstm_attention import SlungLoadNet
from slungload.physics import VehicleConstants
from slungload.state import QUAT, STATE_DIM

torch.set_num_threads(1)

M = 50
PHYSICS_STEP = PhysicsStepNet.architecture
# Constants other than the defaults, each of those f reads changed.
OTHER_PARAMS = VehicleParams(
    mass_quad=1.5, mass_load=0.15, cable_length=0.85, load_damping=0.05, dt=0.025,
    gravity=9.8, thrust_gain=1.12,
)  # fmt: skip


@pytest.mark.parametrize(
    "config",
    [
        ModelConfig(),
        ModelConfig(slack=False, relative_positions=False),
        ModelConfig(residual=False),
        ModelConfig(normalize=False),
    ],
    ids=["default", "absolute-no-slack", "non-residual", "raw-units"],
)
@pytest.mark.parametrize("horizon", [25, 50])
def test_predictions_match_the_eager_network(
    untrained_predictor, physics_flight, config: ModelConfig, horizon: int
):
    predictor = untrained_predictor(config)
    compiled = CompiledPredictor(predictor)
    test_flights = [physics_flight(f"t{i}", 100 + i, M + horizon + 15) for i in range(2)]
    windows = make_windows(test_flights, WindowConfig(history=M, horizon=horizon, stride=5))
    history, future = predict_args(windows)
    got, want = compiled.predict(history, future), predictor.predict(history, future)
    assert got.shape == want.shape == (len(windows), horizon, STATE_DIM)
    assert got.dtype == np.float64
    np.testing.assert_allclose(got, want, atol=PARITY_TOLERANCE, rtol=0)
    np.testing.assert_allclose(np.linalg.norm(got[..., QUAT], axis=-1), 1.0, atol=1e-6)
    # The predictions follow the inputs: a changed future moves them far more than the two
    # paths disagree.
    bumped = future.copy()
    bumped[:, : horizon // 2] += [3.0, 1.0, -1.0, 0.5]
    moved = compiled.predict(history, bumped)
    np.testing.assert_allclose(moved, predictor.predict(history, bumped), atol=PARITY_TOLERANCE)
    assert np.abs(moved - got).max() > 100 * np.abs(got - want).max()


def test_quaternion_sign_jumps_and_scale_in_the_history_change_nothing(
    untrained_predictor, physics_flight
):
    predictor = untrained_predictor()
    compiled = CompiledPredictor(predictor)
    windows = make_windows([physics_flight("t", 7, M + 40)], WindowConfig(history=M, horizon=25))
    histories, futures = predict_args(windows[:1])
    history, future = histories[0], futures[0]
    base = compiled.predict(history, future)
    flipped = history.copy()
    flipped[20:35, QUAT] *= -1.0  # q and -q: the same attitude
    flipped[:, QUAT] *= 1.05  # not unit, within the tolerance: normalised on the way in
    np.testing.assert_allclose(compiled.predict(flipped, future), base, atol=1e-5)
    np.testing.assert_allclose(predictor.predict(flipped, future), base, atol=PARITY_TOLERANCE)
    flipped[:, QUAT] *= 1.7  # far from unit: wrong columns or a broken estimator, refused
    for fn in (compiled.predict, predictor.predict):
        with pytest.raises(ValueError, match=r"row 0 has a quaternion of norm 1\.7\d.*x-y-z-w"):
            fn(flipped, future)


def test_unbatched_call_and_checks(untrained_predictor):
    compiled = CompiledPredictor(untrained_predictor(), warm_up=False)
    history = np.zeros((M, 17))
    history[:, QUAT.stop - 1] = 1.0  # w, last in the file layout (x-y-z-w)
    out = compiled.predict(history, np.zeros((7, 4)))
    assert out.shape == (7, STATE_DIM) and np.isfinite(out).all()
    with pytest.raises(ValueError, match=r"CompiledPredictor\.predict.*history"):
        compiled.predict(np.zeros((M, 13)), np.zeros((7, 4)))
    with pytest.raises(ValueError, match=r"CompiledPredictor\.predict"):
        compiled.predict(history, np.full((7, 4), math.nan))


def test_other_layer_counts_are_refused_by_the_batch_1_predictor_only():
    net = SlungLoadNet(ModelConfig(embed_sizes=(64, 64)))
    assert "three embedding" in unsupported(net)
    with pytest.raises(ValueError, match="three embedding"):
        CompiledPredictor(Predictor(net, WindowConfig(), VehicleParams(), "x"), warm_up=False)
    assert len(fold(net).embed) == 2  # the fold takes any layer count (the batched backend)


@pytest.mark.parametrize("architecture", sorted(MODELS))
def test_the_heading_frame_matches_the_eager_network(
    untrained_predictor, physics_step_predictor, physics_flight, architecture
):
    """A network that sees its windows in the heading frame, on histories heading 2 rad from x:
    the batch-1 compiled pass turns them as the eager network does."""
    from dataclasses import replace as replace_fields

    from slungload.state import rotate_about_z

    config = ModelConfig(architecture=architecture, heading_frame=True)
    if architecture == PHYSICS_STEP:
        predictor = physics_step_predictor(config, VehicleParams())
    else:
        predictor = untrained_predictor(config)
    compiled = CompiledPredictor(predictor)
    flights = [physics_flight(f"t{i}", 100 + i, M + 40) for i in range(2)]
    windows = make_windows(flights, WindowConfig(history=M, horizon=25, stride=5))
    states, aux = rotate_about_z(windows.states, windows.aux, 2.0)
    history, future = predict_args(replace_fields(windows, states=states, aux=aux))
    got, want = compiled.predict(history, future), predictor.predict(history, future)
    np.testing.assert_allclose(got, want, atol=PARITY_TOLERANCE, rtol=0)
    np.testing.assert_allclose(np.linalg.norm(got[..., QUAT], axis=-1), 1.0, atol=1e-6)
    # one window alone, unbatched, is the same window of the batch
    np.testing.assert_allclose(compiled.predict(history[1], future[1]), got[1], atol=1e-6)


# --- the physics-step network compiled --------------------------------------------------------


@pytest.fixture(scope="module")
def physics_step_predictor(physics_flight):
    """Factory ``(config, params, zero_head=False) -> Predictor`` of a physics-step network of
    ``config`` (random weights, normalisation fitted on physics windows) with constants
    ``params``; M = 50, N = 25. ``zero_head`` zeroes the head's last layer (f alone).

    Without normalisation the head's output is the correction in physical units, and random
    weights give O(0.3) m and m/s per step: 70 m/s after 50 steps, where float32 round-off
    alone exceeds ``PARITY_TOLERANCE``. There the last layer is scaled to corrections of a
    step's size (~0.03), what a trained network outputs."""
    paper = WindowConfig(history=M, horizon=25)
    fitting = make_windows([physics_flight(f"f{i}", i, 150) for i in range(3)], paper)

    def make(config: ModelConfig, params: VehicleParams, zero_head: bool = False) -> Predictor:
        torch.manual_seed(0)
        model = build(config, params)
        if config.normalize:
            model.fit_normalization(fitting.states, fitting.inputs, origin_step=M - 1)
        last = model.head.layers[-1]
        with torch.no_grad():
            if zero_head:
                last.weight.zero_()
                last.bias.zero_()
            elif not config.normalize:
                last.weight.mul_(0.1)
                last.bias.mul_(0.1)
        return Predictor(model.eval(), paper, params, "proposed")

    return make


@pytest.mark.parametrize(
    "change",
    [{}, {"normalize": False}, {"relative_positions": False, "slack": False},
     {"load_estimate": "smoothed"}],
    ids=["default", "raw-units", "absolute-no-slack", "smoothed"],
)  # fmt: skip
@pytest.mark.parametrize("params", [VehicleParams(), OTHER_PARAMS], ids=["default", "other"])
@pytest.mark.parametrize("horizon", [25, 50])
def test_physics_step_predictions_match_the_eager_network(
    physics_step_predictor, physics_flight, change, params: VehicleParams, horizon: int
):
    config = ModelConfig(architecture=PHYSICS_STEP, **change)
    predictor = physics_step_predictor(config, params)
    compiled = CompiledPredictor(predictor)
    assert compiled.weights.mode == PHYSICS_STEP_MODE
    assert compiled.weights.architecture == PHYSICS_STEP
    assert compiled.weights.vehicle == VehicleConstants.of(params)
    flights = [physics_flight(f"t{i}", 100 + i, M + horizon + 15) for i in range(2)]
    windows = make_windows(flights, WindowConfig(history=M, horizon=horizon, stride=5))
    history, future = predict_args(windows)
    got, want = compiled.predict(history, future), predictor.predict(history, future)
    np.testing.assert_allclose(got, want, atol=PARITY_TOLERANCE, rtol=0)
    np.testing.assert_allclose(np.linalg.norm(got[..., QUAT], axis=-1), 1.0, atol=1e-6)
    # The head's correction matters (a zero head predicts far from this), and the inputs
    # reach the prediction through f and the network.
    zero = CompiledPredictor(physics_step_predictor(config, params, zero_head=True))
    assert np.abs(zero.predict(history, future) - got).max() > 100 * np.abs(got - want).max()
    bumped = future.copy()
    bumped[:, : horizon // 2, 0] += 2.0  # thrust, N
    moved = compiled.predict(history, bumped)
    np.testing.assert_allclose(moved, predictor.predict(history, bumped), atol=PARITY_TOLERANCE)
    assert np.abs(moved - got).max() > 100 * np.abs(got - want).max()


@pytest.mark.parametrize("params", [VehicleParams(), OTHER_PARAMS], ids=["default", "other"])
def test_zero_head_physics_step_compiled_is_the_physics_rollout(
    physics_step_predictor, physics_flight, params: VehicleParams
):
    """With the head's last layer zero, the compiled network is ``physics.rollout`` from x_{M-1}
    and the load state estimated from x_{M-2}, x_{M-1} (the physics-only row), in its own
    constants."""
    config = ModelConfig(architecture=PHYSICS_STEP)
    compiled = CompiledPredictor(physics_step_predictor(config, params, zero_head=True))
    windows = make_windows(
        [physics_flight(f"z{i}", 30 + i, M + 40) for i in range(2)], WindowConfig(M, 25, 7)
    )
    history, future = predict_args(windows)
    states = windows.states.double()  # package layout, w-x-y-z
    inputs = windows.inputs.double()
    aux = estimate_load_state(states[:, M - 2 : M], params)[:, -1]
    rolled, _ = physics.rollout(states[:, M - 1], aux, inputs[:, M - 1 : -1], params)
    want = rolled.numpy()
    want[..., QUAT] /= np.linalg.norm(want[..., QUAT], axis=-1, keepdims=True)
    want[..., QUAT] = want[..., QUAT][..., [1, 2, 3, 0]]  # file layout x-y-z-w
    got = compiled.predict(history, future)
    # float32 history and arithmetic against a float64 rollout over 25 steps.
    np.testing.assert_allclose(got, want, atol=PARITY_TOLERANCE, rtol=0)
    assert np.abs(want[:, -1] - history[:, -1, :13]).max() > 1e-2  # not a trivial rollout


def test_physics_step_needs_two_history_rows(physics_step_predictor):
    predictor = physics_step_predictor(ModelConfig(architecture=PHYSICS_STEP), VehicleParams())
    predictor.any_history = True
    compiled = CompiledPredictor(predictor, warm_up=False)
    history = np.zeros((1, 17))
    history[:, QUAT.stop - 1] = 1.0  # w, last in the file layout (x-y-z-w)
    with pytest.raises(ValueError, match=r"M >= 2"):
        compiled.predict(history, np.zeros((3, 4)))


def test_compiled_architectures_are_registered_and_others_refused():
    assert set(COMPILED_ARCHITECTURES) <= set(MODELS)
    assert COMPILED_ARCHITECTURES == (SlungLoadNet.architecture, PHYSICS_STEP)
    for name in COMPILED_ARCHITECTURES:
        assert unsupported(build(ModelConfig(architecture=name))) is None

    class Renamed(PhysicsStepNet):  # the decoder of physics-step under another name
        architecture = "renamed"

    renamed = Renamed.__new__(Renamed)
    torch.nn.Module.__init__(renamed)
    renamed.config = ModelConfig(architecture=PHYSICS_STEP)
    assert "does not support the 'renamed' architecture" in unsupported(renamed)
    with pytest.raises(ValueError, match="'renamed' architecture"):
        fold(renamed)

    class Impostor(SlungLoadNet):  # claims physics-step without being one
        architecture = PHYSICS_STEP

    impostor = Impostor.__new__(Impostor)
    torch.nn.Module.__init__(impostor)
    impostor.config = ModelConfig()
    assert "'physics-step'" in unsupported(impostor)
