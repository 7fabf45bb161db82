"""One model for many loads: windows carry their flights' constants, the physics model runs
with the dataset's, a window's in-flight estimate or the flight's own (the truth), and the
physics-step network adapts f to each window's estimate (``ModelConfig.constants =
"window"``), the same on the eager, ONNX and compiled paths."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest
import torch
from flights import ADAPTIVE, predict_args
from flights import ADAPTIVE_WINDOW as WINDOW

from slungload.config import ModelConfig, VehicleParams
from slungload.constants_estimate import ADAPT_RANGE, adapted
from slungload.data import load_dataset
from slungload.deploy.compiled import CompiledNetworkModel, CompiledPhysicsModel, CompiledPredictor
from slungload.deploy.compiled.batched import with_backend
from slungload.deploy.onboard import OnnxPredictor
from slungload.deploy.onnx import export
from slungload.deploy.predictor import PARITY_TOLERANCE, Predictor
from slungload.load_state import estimate_load_state
from slungload.models import PhysicsStepNet
from slungload.models.prediction import NetworkModel, PhysicsModel
from slungload.physics import VehicleConstants, rollout
from slungload.run_config import RunConfig
from slungload.sim import SimConfig

torch.set_num_threads(1)


def _rmse(pred, windows) -> float:
    return float((pred.double() - windows.future.states.double()).square().mean().sqrt())


def test_windows_carry_their_flights_constants(varied, tmp_path):
    ds, windows = varied
    names = windows.names
    for i in range(len(windows)):
        own = ds.flights[names[int(windows.flight[i])]].constants
        assert tuple(windows.constants[i].tolist()) == tuple(VehicleConstants.of(own))
    part = windows[[3, 1]]
    assert torch.equal(part.constants, windows.constants[[3, 1]])
    assert part.vehicle().cable_length.shape == (2,)
    # The cache rebuilds them; a dataset of one load has none.
    first = load_dataset(ds.folder, window=WINDOW, cache_dir=tmp_path)
    again = load_dataset(ds.folder, window=WINDOW, cache_dir=tmp_path)
    assert again.from_cache
    for split in first.splits:
        a, b = first.splits[split].constants, again.splits[split].constants
        assert (a is None and b is None) or torch.equal(a, b)


def test_physics_with_the_flights_constants_rolls_each_window_with_its_own(varied):
    """The "flight" row: each window rolled out with its flight's recorded constants, the load
    rate at M-1 estimated with its own cable length."""
    ds, windows = varied
    got = PhysicsModel(ds.params, constants="flight").predict_windows(windows)
    m = WINDOW.history
    for i in (0, len(windows) // 2, len(windows) - 1):
        own = ds.flights[windows.names[int(windows.flight[i])]].constants
        states = windows.states[i : i + 1].double()
        aux = estimate_load_state(states[:, m - 2 : m], own)[:, -1]
        want, _ = rollout(
            states[:, m - 1], aux, windows.inputs[i : i + 1, m - 1 : -1].double(), own
        )
        torch.testing.assert_close(got[i : i + 1].double(), want, atol=1e-5, rtol=0)


def test_the_truth_beats_the_nominal_constants_and_the_estimate_comes_close(varied):
    ds, windows = varied
    error = {
        source: _rmse(PhysicsModel(ds.params, constants=source).predict_windows(windows), windows)
        for source in ("dataset", "window", "flight")
    }
    # Measured 0.192 / 0.194 / 0.216 m: the unmodelled effects (wind, drag, thrust lag) stay.
    assert error["flight"] < error["window"] < 0.95 * error["dataset"], error
    est = adapted(windows.history.states.double(), windows.history.inputs.double(), ds.params)
    truth = windows.vehicle()
    length = (est.cable_length / truth.cable_length - 1).abs()
    assert float(length.median()) < 0.02  # the cable length from one window
    low, high = ADAPT_RANGE["mass_load"]
    assert bool((est.mass_load >= low * ds.params.mass_load).all())
    assert bool((est.mass_load <= high * ds.params.mass_load).all())


def test_the_estimates_mass_prior_pulls_physics_towards_the_nominal_load(varied):
    from dataclasses import replace

    ds, windows = varied
    m = WINDOW.history
    x, u_past = windows.states[5, :m].double(), windows.inputs[5, : m - 1].double()
    plans = windows.inputs[5, m - 1 : -1].double().expand(4, -1, -1) + 0.3 * torch.randn(4, 25, 4)
    u = torch.cat([u_past, plans[0, :1]])
    # An overwhelming prior keeps the nominal mass: physics on the window's cable length alone.
    cable = float(adapted(x, u, ds.params, 1e12).cable_length)
    held = PhysicsModel(ds.params, constants="window", prior_weight=1e12)
    own = PhysicsModel(replace(ds.params, cable_length=cable))
    want = own.predict_candidates(x, u_past, plans)
    torch.testing.assert_close(held.predict_candidates(x, u_past, plans), want, atol=1e-9, rtol=0)
    free = PhysicsModel(ds.params, constants="window", prior_weight=0.0)
    assert (free.predict_candidates(x, u_past, plans) - want).abs().max() > 1e-4  # mass moves it
    # The compiled copy takes the same prior, also when made from the eager model.
    for prior, model in ((1e12, held), (0.0, free)):
        compiled = with_backend(model, "compiled")
        assert compiled.prior_weight == prior
        torch.testing.assert_close(compiled.predict_candidates(x, u_past, plans),
                                   model.predict_candidates(x, u_past, plans),
                                   atol=1e-10, rtol=0)  # fmt: skip
    with pytest.raises(ValueError, match="no estimate"):
        PhysicsModel(ds.params, prior_weight=1.0)
    with pytest.raises(ValueError, match=">= 0"):
        PhysicsModel(ds.params, constants="window", prior_weight=-1.0)


def test_physics_with_the_flights_constants_needs_them(physics_flight):
    from slungload.data.windows import make_windows

    windows = make_windows([physics_flight("p", 1, 90)], WINDOW, VehicleParams())
    assert windows.constants is None  # no flight records its own
    with pytest.raises(ValueError, match="records its own"):
        PhysicsModel(VehicleParams(), constants="flight").predict_windows(windows)
    with pytest.raises(ValueError, match="unknown constants source"):
        PhysicsModel(VehicleParams(), constants="truth")


def test_the_adaptive_network_with_a_zero_head_is_physics_with_the_window_estimate(varied):
    ds, windows = varied
    torch.manual_seed(0)
    net = PhysicsStepNet(ADAPTIVE, ds.params).double()
    net.fit_normalization(windows.states.double(), windows.inputs.double(), origin_step=49)
    with torch.no_grad():
        net.head.layers[-1].weight.zero_()
        net.head.layers[-1].bias.zero_()
    net.eval()
    m = WINDOW.history
    w = windows.states.double(), windows.inputs.double()
    with torch.no_grad():
        got = net(w[0][:, :m], w[1][:, :m], w[1][:, m:]).states
    want = PhysicsModel(ds.params, constants="window").predict_windows(
        dataclasses.replace(windows, states=w[0], inputs=w[1])
    )
    torch.testing.assert_close(got, want, atol=1e-8, rtol=0)
    # ... which is not the dataset's constants' rollout.
    nominal = PhysicsModel(ds.params).predict_windows(windows)
    assert (got.float() - nominal).abs().max() > 1e-2


def test_constants_are_a_physics_step_option_recorded_in_the_run():
    with pytest.raises(ValueError, match="physics-step network"):
        ModelConfig(constants="window")
    with pytest.raises(ValueError, match="unknown constants source"):
        ModelConfig(architecture="physics-step", constants="flight")  # a network sees no truth
    run = RunConfig(
        model=ModelConfig.sized("small", architecture="physics-step", constants="window")
    )
    assert run.model.adapts_constants and not ModelConfig().adapts_constants
    assert "adaptive" in run.folder() and run.label().endswith("+adaptive")
    assert RunConfig.from_toml(run.to_toml()) == run


@pytest.fixture(scope="module")
def adaptive_predictor(varied):
    ds, windows = varied
    torch.manual_seed(1)
    net = PhysicsStepNet(ADAPTIVE, ds.params)
    net.fit_normalization(windows.states, windows.inputs, origin_step=49)
    return Predictor(net.eval(), WINDOW, ds.params, "proposed"), windows


def _paths_agree(predictor, windows, onnx_path):
    """Eager, ONNX and compiled batch-1 predictions of six windows agree; returns the compiled
    predictor and those windows' (history, future inputs)."""
    history, future = predict_args(windows[:6])
    want = predictor.predict(history, future)
    result = export(predictor, onnx_path)
    assert result.max_abs_diff <= PARITY_TOLERANCE
    got = OnnxPredictor(result.model).predict(history, future)
    np.testing.assert_allclose(got, want, atol=PARITY_TOLERANCE, rtol=0)
    compiled = CompiledPredictor(predictor)
    np.testing.assert_allclose(compiled.predict(history, future), want, atol=PARITY_TOLERANCE)
    return compiled, (history, future)


def test_onnx_and_compiled_adaptive_networks_match_eager(adaptive_predictor, tmp_path):
    predictor, windows = adaptive_predictor
    compiled, (history, future) = _paths_agree(predictor, windows, tmp_path / "adaptive.onnx")
    with pytest.raises(ValueError, match="the last 50 rows"):
        compiled.predict(history[:, :10], future)


def test_adaptive_candidates_agree_on_every_backend(adaptive_predictor, varied):
    predictor, windows = adaptive_predictor
    ds, _ = varied
    m = WINDOW.history
    x, u_past = windows.states[5, :m], windows.inputs[5, : m - 1]
    plans = windows.inputs[5, m - 1 : -1].expand(6, -1, -1) + 0.3 * torch.randn(6, 25, 4)
    eager = NetworkModel(predictor.model, m).predict_candidates(x, u_past, plans)
    compiled = CompiledNetworkModel(predictor.model, m).predict_candidates(x, u_past, plans)
    torch.testing.assert_close(compiled, eager, atol=PARITY_TOLERANCE, rtol=0)
    x, u_past, plans = x.double(), u_past.double(), plans.double()
    physics = PhysicsModel(ds.params, constants="window")
    assert physics.history == m
    want = physics.predict_candidates(x, u_past, plans)
    got = CompiledPhysicsModel(ds.params, constants="window").predict_candidates(x, u_past, plans)
    torch.testing.assert_close(got, want, atol=1e-10, rtol=0)
    nominal = PhysicsModel(ds.params).predict_candidates(x, u_past, plans)
    assert (want - nominal).abs().max() > 1e-3


def test_the_report_shows_physics_with_the_flights_constants_beside_the_dataset_s(varied, tmp_path):
    from slungload.evaluation.evaluator import evaluate
    from slungload.evaluation.results import PHYSICS, PHYSICS_TRUTH

    ds, _ = varied
    report = evaluate([], data=ds.folder, horizons=(25,), progress=False, out=tmp_path)
    assert report.labels[:2] == (PHYSICS, PHYSICS_TRUTH)
    rmse = {r.label: r.metrics.rmse["combined"] for r in report.results}
    assert rmse[PHYSICS_TRUTH] != rmse[PHYSICS]
    assert "each flight with its own recorded load mass" in (tmp_path / "report.md").read_text()


def test_train_takes_the_constants_option():
    from slungload.cli import build_parser
    from slungload.cli.train import run_from_args

    base = ["train", "--data", "d", "--out", "o", "--model", "physics-step"]
    run = run_from_args(build_parser().parse_args([*base, "--constants", "window"]))
    assert run.model.constants == "window" and run.model.architecture == "physics-step"
    assert run_from_args(build_parser().parse_args(base)).model.constants == "dataset"
    with pytest.raises(ValueError, match="physics-step network"):
        run_from_args(build_parser().parse_args(["train", "--data", "d", "--out", "o",
                                                 "--constants", "window"]))  # fmt: skip


# --- in closed loop: the MPC on loads it never saw ----------------------------------------


class _Still:
    """A numpy candidate model: every candidate stays where the history ends."""

    name, history, numpy = "still", 20, True

    def predict_candidates(self, x_hist, u_past, plans):
        return np.broadcast_to(x_hist[-1], (*plans.shape[:2], x_hist.shape[1])).copy()


def _hanging(length: float, m: int = 20) -> np.ndarray:
    """(m, 13): the vehicle hovering 1.5 m up, level, the load ``length`` below it."""
    x = np.zeros((m, 13))
    x[:, 2], x[:, 6], x[:, 12] = 1.5, 1.0, 1.5 - length
    return x


def test_the_mpc_cost_follows_the_in_flight_estimate():
    from slungload.control.mpc import InputLimits, MPCConfig, SamplingMPC, window_estimate
    from slungload.control.mppi import MPPIController, ReferenceAhead

    params, limits = VehicleParams(), InputLimits.from_sim(SimConfig())
    window = MPCConfig(samples=8, constants="window")
    with pytest.raises(ValueError, match="needs an estimate"):
        MPPIController(_Still(), limits, window, params)
    with pytest.raises(ValueError, match="needs constants='window'"):
        MPPIController(_Still(), limits, MPCConfig(samples=8), params, lambda x, u: (1.0, 0.1))
    with pytest.raises(ValueError, match="unknown 'truth'"):
        MPCConfig(constants="truth")
    short = _Still()
    short.history = 5
    with pytest.raises(ValueError, match="M >= 17"):
        SamplingMPC(short, limits, window, params)

    mpc = MPPIController(_Still(), limits, window, params, lambda x, u: (1.1, 0.3))
    assert mpc.cable_length == params.cable_length  # the prior until the first step
    n = window.horizon
    ref = ReferenceAhead(np.tile([0.0, 0.0, 1.5], (n, 1)), np.zeros((n, 3)), np.zeros(n))
    mpc.step(_hanging(1.1)[0], ref)
    assert mpc.cable_length == 1.1
    assert mpc.hover_thrust == pytest.approx((params.mass_quad + 0.3) * params.gravity)
    # the package's estimate: a load hanging still is as long as it hangs, and as heavy as the
    # prior says (no motion tells its mass)
    length, mass = window_estimate(params)(_hanging(0.9), np.tile([14.0, 0, 0, 0], (19, 1)))
    assert length == pytest.approx(0.9) and mass == pytest.approx(params.mass_load)


def test_a_network_given_the_constants_is_the_adaptive_one_at_its_estimate(adaptive_run, varied,
                                                                            tiny_run):  # fmt: skip
    from slungload.control.mpc import window_estimate
    from slungload.models.prediction import load_prediction_model

    _, windows = varied
    m = WINDOW.history
    x, u_past = windows.states[9, :m].double(), windows.inputs[9, : m - 1].double()
    plans = windows.inputs[9, m - 1 : -1].double().expand(4, -1, -1) + 0.3 * torch.randn(4, 25, 4)
    adaptive = load_prediction_model(adaptive_run)
    length, mass = window_estimate(adaptive.net.params)(x.numpy(), u_past.numpy())
    truth = dataclasses.replace(adaptive.net.params, cable_length=length, mass_load=mass)
    given = load_prediction_model(adaptive_run, constants=truth)
    assert given.net.config.constants == "dataset" and given.net.params == truth
    want = adaptive.predict_candidates(x, u_past, plans)
    torch.testing.assert_close(given.predict_candidates(x, u_past, plans), want, atol=1e-4, rtol=0)
    other = dataclasses.replace(truth, cable_length=1.3 * length)
    moved = load_prediction_model(adaptive_run, constants=other)
    moved = moved.predict_candidates(x, u_past, plans)
    assert (moved - want).abs().max() > 1e-3
    with pytest.raises(ValueError, match="only a physics-step network"):
        load_prediction_model(tiny_run.out, constants=truth)


# --- a network that sees its constants (``ModelConfig.constants_input``) ------------------

SEEING = dataclasses.replace(ADAPTIVE, constants_input=True)


@pytest.fixture(scope="module")
def seeing_predictor(varied):
    """An adaptive network that also sees f's constants, its constants' columns non-zero."""
    ds, windows = varied
    torch.manual_seed(2)
    net = PhysicsStepNet(SEEING, ds.params)
    net.fit_normalization(windows.states, windows.inputs, origin_step=49)
    with torch.no_grad():
        net.embed.layers[0].weight[:, -2:].normal_(0.0, 2.0)
    return Predictor(net.eval(), WINDOW, ds.params, "proposed"), windows


def test_a_network_that_sees_its_constants_is_the_adaptive_one_when_it_ignores_them(
    varied, seeing_predictor
):
    ds, windows = varied
    seeing = seeing_predictor[0].model
    adaptive = PhysicsStepNet(ADAPTIVE, ds.params)
    state = dict(seeing.state_dict())
    first = state["embed.layers.0.weight"]
    assert first.shape[1] == 17 + 2  # state, input, cable length, load mass
    adaptive.load_state_dict({**state, "embed.layers.0.weight": first[:, :17]})
    adaptive.eval()
    m = WINDOW.history
    args = windows.states[:, :m], windows.inputs[:, :m], windows.inputs[:, m:]
    with torch.no_grad():
        sees = seeing(*args).states
        ignores = adaptive(*args).states
        seeing.embed.layers[0].weight[:, -2:] = 0.0
        blind = seeing(*args).states
        seeing.embed.layers[0].weight.copy_(first)
    torch.testing.assert_close(blind, ignores, atol=1e-6, rtol=0)
    assert (sees - ignores).abs().max() > 1e-3
    # what it sees: the window's estimate against the network's own constants
    est = adapted(windows.history.states, windows.history.inputs, ds.params)
    ratio = est.cable_length / ds.params.cable_length - 1
    carry = seeing.start_rollout(args[0] - seeing.origin(args[0][:, -1]).unsqueeze(1), *args[1:])
    torch.testing.assert_close(seeing.conditioning(carry)[:, 0], ratio)


def test_a_network_that_sees_its_constants_agrees_on_every_path(seeing_predictor, tmp_path):
    predictor, windows = seeing_predictor
    _paths_agree(predictor, windows, tmp_path / "seeing.onnx")
    # candidates, in flight and given fixed constants (the truth's path; on a copy, the
    # fixture's network stays adaptive)
    m = WINDOW.history
    x, u_past = windows.states[5, :m], windows.inputs[5, : m - 1]
    plans = windows.inputs[5, m - 1 : -1].expand(6, -1, -1) + 0.3 * torch.randn(6, 25, 4)
    net = predictor.model
    for given in (None, dataclasses.replace(net.params, cable_length=1.2, mass_load=0.3)):
        if given is not None:
            net = copy.deepcopy(net)
            net.params, net.config = given, dataclasses.replace(net.config, constants="dataset")
        eager = NetworkModel(net, m).predict_candidates(x, u_past, plans)
        fast = CompiledNetworkModel(net, m).predict_candidates(x, u_past, plans)
        torch.testing.assert_close(fast, eager, atol=PARITY_TOLERANCE, rtol=0)
    with torch.no_grad():  # the candidates' shared encoder sees what a whole window's does
        shared = net.forward_candidates(x, u_past, plans).states
        alone = net(x.expand(6, -1, -1), torch.cat([u_past.expand(6, -1, -1), plans[:, :1]], 1),
                    torch.cat([plans[:, 1:], plans[:, -1:]], 1)).states  # fmt: skip
    torch.testing.assert_close(shared, alone, atol=1e-5, rtol=0)


def test_only_the_physics_step_network_sees_its_constants():
    with pytest.raises(ValueError, match="constants_input is for the physics-step"):
        ModelConfig(constants_input=True)
    run = RunConfig(model=dataclasses.replace(SEEING))
    assert RunConfig.from_toml(run.to_toml()) == run
