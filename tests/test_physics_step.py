"""The physics-step architecture: the paper's network correcting one step of the discrete model
per decoder step (``models.physics_step``), from its arithmetic to its checkpoint and exports."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from flights import SMALL, TINY, predict_args

from slungload.config import LossWeights, ModelConfig, VehicleParams, WindowConfig, to_dict
from slungload.data.dataset import load_dataset
from slungload.data.windows import make_windows
from slungload.deploy.compiled import CompiledPredictor, unsupported
from slungload.deploy.onboard import OnnxPredictor
from slungload.deploy.onnx import export
from slungload.deploy.predictor import PARITY_TOLERANCE, Predictor
from slungload.load_state import estimate_load_state, fit_load_state
from slungload.loss import LOSS_VARIANTS, compute_loss, model_config_for
from slungload.models import (
    MODELS,
    PhysicsStepNet,
    SlungLoadNet,
    architecture_of,
    build,
    count_parameters,
    load_checkpoint,
)
from slungload.physics import rollout
from slungload.smoothing import LOAD_FIT_STEPS, load_fit_coefficients
from slungload.state import LOAD_POS, POS, QUAT

torch.set_num_threads(1)

NAME = "physics-step"
PS_TINY = dataclasses.replace(TINY, architecture=NAME)  # the tiny network of every training test
# Small, but with every kind of layer the paper's network has (stacked LSTMs with dropout, a
# three-Linear head whose first two Linears are joined).
SMALL_NET = ModelConfig(
    architecture=NAME, embed_sizes=(16, 16, 16), hidden_size=8, num_layers=2,
    head_sizes=(16, 16, 16), dropout=0.1,
)  # fmt: skip
M, N = 10, 8  # the windows of the arithmetic tests
OTHER_PARAMS = VehicleParams(mass_load=0.12, cable_length=0.72)  # not the defaults


@pytest.fixture(scope="module")
def windows(physics_flight) -> tuple[torch.Tensor, torch.Tensor]:
    """States (4, M+N, 13) and inputs (4, M+N, 4), float64, package layout: windows of four
    physics flights, each moved to its own spot of the arena (so relative and absolute
    positions differ)."""
    flights = [physics_flight(f"w{seed}", seed, M + N + 5) for seed in range(4)]
    states = torch.stack([torch.from_numpy(f.states[5:]) for f in flights])
    inputs = torch.stack([torch.from_numpy(f.inputs[5:]) for f in flights])
    shift = torch.tensor([[3.0, -2.0, 1.5]], dtype=torch.float64) * torch.arange(4.0)[:, None]
    states[..., POS] += shift[:, None]
    states[..., LOAD_POS] += shift[:, None]
    return states, inputs


def fitted(config: ModelConfig, states, inputs) -> PhysicsStepNet:
    """A fresh network of ``config`` in the windows' dtype, normalised on them if it normalises."""
    torch.manual_seed(0)
    net = build(config, VehicleParams()).to(states.dtype)
    if config.normalize:
        net.fit_normalization(states, inputs, origin_step=M - 1)
    return net


def zero_head(net: PhysicsStepNet) -> PhysicsStepNet:
    with torch.no_grad():
        net.head.layers[-1].weight.zero_()
        net.head.layers[-1].bias.zero_()
    return net


def physics_only(states, inputs, params: VehicleParams, estimate: str = "difference"):
    """``physics.rollout`` from x_{M-1} and the load state estimated from x_{M-2}, x_{M-1}
    (or, "smoothed", fitted through the last LOAD_FIT_STEPS states)."""
    if estimate == "smoothed":
        aux = fit_load_state(states[:, M - LOAD_FIT_STEPS : M], params)
    else:
        aux = estimate_load_state(states[:, M - 2 : M], params)[:, -1]
    return rollout(states[:, M - 1], aux, inputs[:, M - 1 : M + N - 1], params)[0]


# --- the architecture ---------------------------------------------------------------------


def test_registered_by_name_with_the_paper_networks_parameters():
    assert MODELS[NAME] is PhysicsStepNet
    params = VehicleParams(cable_length=0.8)
    net = build(ModelConfig(architecture=NAME), params)
    assert type(net) is PhysicsStepNet and architecture_of(net) == NAME
    assert net.params == params  # the constants f uses are the ones it was built with
    assert count_parameters(net) == count_parameters(SlungLoadNet()) == 238_906
    assert count_parameters(PhysicsStepNet()) == 238_906  # default config names itself
    for config in (PS_TINY, SMALL_NET, dataclasses.replace(PS_TINY, slack=False)):
        paper = dataclasses.replace(config, architecture=SlungLoadNet.architecture)
        assert count_parameters(build(config)) == count_parameters(build(paper))
        # Same layers, same names: a state_dict fits both.
        assert build(config).state_dict().keys() == build(paper).state_dict().keys()


def test_refuses_other_configs_and_short_histories():
    with pytest.raises(ValueError, match="'lstm-attention'"):
        PhysicsStepNet(ModelConfig())
    with pytest.raises(ValueError, match="residual=False"):
        PhysicsStepNet(dataclasses.replace(PS_TINY, residual=False))
    net = PhysicsStepNet(PS_TINY)
    x, u = torch.randn(2, 1, 13), torch.randn(2, 3, 4)
    with pytest.raises(ValueError, match="M >= 2"):
        net(x, u[:, :1], u[:, 1:])


def test_smoothed_load_estimate_is_exact_at_constant_acceleration_and_quieter():
    # Vehicle and cable vector r = pL - p accelerating uniformly: the quadratic fit's slopes
    # are the velocities at the last sample, where the backward difference lags half a step.
    params = VehicleParams()
    h, k = params.dt, LOAD_FIT_STEPS
    t = (torch.arange(-k + 1, 1, dtype=torch.float64) * h)[:, None]  # (K, 1), last at 0
    f64 = torch.float64
    v0, acc = torch.tensor([0.3, 0.2, -0.1], dtype=f64), torch.tensor([0.5, -1.0, 2.0], dtype=f64)
    r0, w = torch.tensor([0.1, 0.0, -0.7], dtype=f64), torch.tensor([0.2, -0.1, 0.0], dtype=f64)
    b = torch.tensor([-1.0, 0.5, 0.3], dtype=f64)
    p = v0 * t + 0.5 * acc * t**2
    r = r0 + w * t + 0.5 * b * t**2
    x = torch.zeros(1, k, 13, dtype=torch.float64)
    x[0, :, POS], x[0, :, QUAT.start], x[0, :, LOAD_POS] = p, 1.0, p + r
    got = fit_load_state(x, params)[0]
    want_rate = torch.linalg.cross(r0 / r0.norm(), w) / params.cable_length
    torch.testing.assert_close(got, torch.cat([v0 + w, want_rate]), atol=1e-9, rtol=0)
    lagged = estimate_load_state(x[:, -2:], params)[0, -1]
    assert (lagged[:3] - (v0 + w)).abs().max() > 0.01  # (acc + b) h / 2
    # Noise: the slope's variance is sum c^2 sigma^2, about a ninth of the difference's
    # 2 sigma^2 / h^2; the weights ignore a constant offset.
    c = load_fit_coefficients(k, h)
    assert (c**2).sum() < 0.12 * 2 / h**2 and abs(c.sum()) < 1e-9
    with pytest.raises(ValueError, match=">= 3 steps"):
        load_fit_coefficients(2, h)


def test_load_estimate_is_a_physics_step_option_only():
    with pytest.raises(ValueError, match="physics-step network"):
        ModelConfig(load_estimate="smoothed")
    with pytest.raises(ValueError, match="unknown load estimate"):
        ModelConfig(architecture=NAME, load_estimate="kalman")


@pytest.mark.parametrize(
    "change",
    [{}, {"normalize": False}, {"relative_positions": False}, {"slack": False},
     {"load_estimate": "smoothed"}],
    ids=["default", "normalize=False", "relative_positions=False", "slack=False", "smoothed"],
)  # fmt: skip
def test_zero_head_is_the_physics_only_rollout(windows, change):
    params = VehicleParams()
    states, inputs = windows
    net = zero_head(fitted(dataclasses.replace(PS_TINY, **change), states, inputs)).eval()
    with torch.no_grad():
        pred = net(states[:, :M], inputs[:, :M], inputs[:, M:])
    want = physics_only(states, inputs, params, change.get("load_estimate", "difference"))
    assert pred.states.dtype == torch.float64
    torch.testing.assert_close(pred.states, want, atol=1e-9, rtol=0)  # float64 round-off only
    if change.get("slack") is False:
        assert pred.slack is None
    else:
        assert not pred.slack.any()
    # ... and not a trivial one: the rollout moves away from the last state.
    assert (want[:, -1] - states[:, M - 1]).abs().max() > 1e-2


def test_the_correction_is_the_head_output_times_delta_std(windows):
    """x_hat_M = f(x_{M-1}, u_{M-1}, a_{M-1}) + delta_std * out, out the head's state rows."""
    params = VehicleParams()
    states, inputs = windows
    net = zero_head(fitted(PS_TINY, states, inputs)).eval()
    out = torch.linspace(-1.0, 1.0, 13, dtype=torch.float64)
    with torch.no_grad():
        net.head.layers[-1].bias[:13] = out
        pred = net(states[:, :M], inputs[:, :M], inputs[:, M : M + 1])
    want = physics_only(states, inputs, params)[:, :1] + net.delta_std * out
    torch.testing.assert_close(pred.states, want, atol=1e-9, rtol=0)
    assert not torch.equal(net.delta_std, torch.ones(13, dtype=torch.float64))  # fitted


def test_batched_equals_looped(windows):
    states, inputs = windows
    net = fitted(SMALL_NET, states, inputs).eval()
    with torch.no_grad():
        batch = net(states[:, :M], inputs[:, :M], inputs[:, M:])
        for b in range(len(states)):
            one = net(states[b : b + 1, :M], inputs[b : b + 1, :M], inputs[b : b + 1, M:])
            torch.testing.assert_close(one.states[0], batch.states[b], atol=1e-12, rtol=0)
            torch.testing.assert_close(one.slack[0], batch.slack[b], atol=1e-12, rtol=0)


@pytest.mark.parametrize("variant", list(LOSS_VARIANTS))
def test_every_loss_variant_trains_every_parameter(windows, variant: str):
    params = VehicleParams()
    states, inputs = (w.float() for w in windows)
    config = model_config_for(variant, SMALL_NET)
    net = fitted(config, states, inputs).train()
    pred = net(states[:, :M], inputs[:, :M], inputs[:, M:])
    assert (pred.slack is not None) == LOSS_VARIANTS[variant].slack
    aux = estimate_load_state(states, params)
    terms = compute_loss(
        pred, states, inputs, aux, history=M, params=params, weights=LossWeights(), variant=variant
    )
    terms.total.backward()
    for name, p in net.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
        assert p.grad.abs().max() > 0, f"no gradient reaches {name}"


# --- a trained checkpoint, its export and the compiled path --------------------------------


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory, write_dataset, train_tiny) -> Path:
    """A quick run of the tiny physics-step network on physics flights, with constants other
    than the defaults (so a rebuild with the wrong ones would show)."""
    root = tmp_path_factory.mktemp("physics_step")
    data = write_dataset(root / "data", physics=True)
    dataset = load_dataset(data, window=SMALL, params=OTHER_PARAMS, cache_dir=root / "cache")
    train_tiny(dataset, root / "run", model=PS_TINY)
    return root / "run"


@pytest.fixture(scope="module")
def val_args(physics_flight) -> tuple[np.ndarray, np.ndarray]:
    """``predict``'s arguments, history (W, M, 17) and future inputs (W, N, 4), of SMALL
    windows of an unseen physics flight."""
    return predict_args(make_windows([physics_flight("v", 99, 40)], SMALL))


def test_checkpoint_rebuilds_the_architecture_with_its_constants(run_dir: Path, val_args):
    loaded = load_checkpoint(run_dir / "best.ckpt")
    assert type(loaded.model) is PhysicsStepNet and loaded.model_config.architecture == NAME
    assert loaded.model.params == loaded.params == OTHER_PARAMS
    assert loaded.model.config == loaded.model_config == PS_TINY
    # The rebuilt network predicts (it is not left at its initial weights: normalisation and
    # the trained head are in the state_dict).
    assert not torch.equal(loaded.model.delta_std, torch.ones(13))
    history, future = val_args
    out = Predictor.from_checkpoint(run_dir).predict(history, future)
    assert out.shape == (len(history), SMALL.horizon, 13) and np.isfinite(out).all()


def test_onnx_export_records_the_architecture_and_matches_eager(run_dir, val_args, tmp_path):
    result = export(run_dir, tmp_path / "ps.onnx")
    assert result.max_abs_diff <= PARITY_TOLERANCE
    meta = json.loads(result.sidecar.read_text())
    assert meta["configs"]["model"]["architecture"] == NAME
    assert meta["configs"]["params"] == to_dict(load_checkpoint(run_dir).params)
    history, future = val_args
    onnx, eager = OnnxPredictor(result.model), Predictor.from_checkpoint(run_dir)
    got = onnx.predict(history, future)
    np.testing.assert_allclose(got, eager.predict(history, future), atol=PARITY_TOLERANCE, rtol=0)
    # The graph follows the inputs through f (not frozen to the tracing inputs).
    bumped = future.copy()
    bumped[:, :2, 0] += 2.0  # thrust, N
    moved = onnx.predict(history, bumped)
    np.testing.assert_allclose(moved, eager.predict(history, bumped), atol=PARITY_TOLERANCE, rtol=0)
    assert np.abs(moved - got).max() > 1e-3


def test_onnx_export_of_the_paper_size_network_on_physics_windows(physics_flight, tmp_path):
    """Default sizes, random weights, normalisation fitted on physics windows, N = 25 (the
    smoothed load estimate exports too: tests/test_onboard.py, at a small size)."""
    window = WindowConfig(history=50, horizon=25)
    flights = [physics_flight(f"p{i}", 20 + i, 100) for i in range(3)]
    windows = make_windows(flights, dataclasses.replace(window, stride=9))
    torch.manual_seed(0)
    model = PhysicsStepNet(ModelConfig(architecture=NAME))
    model.fit_normalization(windows.states, windows.inputs, origin_step=window.history - 1)
    predictor = Predictor(model.eval(), window, VehicleParams(), "proposed")
    result = export(predictor, tmp_path / "paper.onnx")
    assert json.loads(result.sidecar.read_text())["configs"]["model"]["architecture"] == NAME
    history, future = predict_args(windows)
    got = OnnxPredictor(result.model).predict(history, future)
    np.testing.assert_allclose(got, predictor.predict(history, future), atol=PARITY_TOLERANCE)
    np.testing.assert_allclose(np.linalg.norm(got[..., QUAT], axis=-1), 1.0, atol=1e-5)


def test_the_compiled_predictor_runs_it_with_its_constants(run_dir: Path, windows, val_args):
    """The compiled path (``deploy.compiled``) compiles the architecture with f's constants of
    the network (not the defaults) and agrees with the eager network; tests/test_compiled.py
    checks it further. The tiny checkpoint's layer structure is refused, not its architecture."""
    reason = unsupported(Predictor.from_checkpoint(run_dir).model)
    assert "three embedding" in reason and "architecture" not in reason
    states, inputs = (w.float() for w in windows)
    torch.manual_seed(0)
    net = build(SMALL_NET, OTHER_PARAMS)
    net.fit_normalization(states, inputs, origin_step=M - 1)
    predictor = Predictor(net.eval(), SMALL, OTHER_PARAMS, "proposed")
    compiled = CompiledPredictor(predictor)
    assert compiled.weights.vehicle.cable_length == OTHER_PARAMS.cable_length
    history, future = val_args
    got = compiled.predict(history, future)
    np.testing.assert_allclose(got, predictor.predict(history, future), atol=PARITY_TOLERANCE)
