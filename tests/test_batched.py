"""Batched rollouts for the MPC (``deploy/compiled/batched.py``): the compiled physics rollout
against ``PhysicsModel`` (float64), the compiled network against the eager ``NetworkModel``
(float32) for both architectures and every model mode, and the backend choice. Their kernels
and their copy of the physics are tested in ``test_compiled_kernels.py`` and
``test_compiled_physics.py``. Nothing is timed here (``slungload benchmark --mpc``)."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from flights import TINY
from test_prediction import candidate_windows, random_history, random_plans

from slungload.config import MODEL_SIZES, PREDICTION_BACKENDS, ModelConfig, VehicleParams
from slungload.control.mpc import TorchCandidates, candidate_model
from slungload.deploy.backends import load_model
from slungload.deploy.compiled import (
    CompiledNetworkModel,
    CompiledPhysicsModel,
    with_backend,
)
from slungload.deploy.predictor import PARITY_TOLERANCE
from slungload.lab.control.oracle import PlantCandidates
from slungload.models import MODELS, PhysicsStepNet, build
from slungload.models.prediction import NetworkModel, PhysicsModel, PredictionModel
from slungload.state import LOAD_POS, POS, QUAT, VEL, rotate_about_z

torch.set_num_threads(1)

PARAMS = VehicleParams()
OTHER_PARAMS = VehicleParams(
    mass_quad=1.5, mass_load=0.15, cable_length=0.85, load_damping=0.05, dt=0.025,
    gravity=9.8, thrust_gain=1.12,
)  # fmt: skip
PHYSICS_STEP = PhysicsStepNet.architecture
M, N, K = 9, 6, 11


# --- the physics model ----------------------------------------------------------------------


def assert_numpy_entry(model, x_hist, u_past, plans, want: torch.Tensor) -> None:
    """The MPC calls a compiled model through its numpy entry (``candidate_model``), no
    tensor at the edges, and gets the torch call's states to the bit."""
    entry = candidate_model(model)
    assert entry.predict_candidates == model.numpy_candidates
    got = entry.predict_candidates(*(t.double().numpy() for t in (x_hist, u_past, plans)))
    assert isinstance(got, np.ndarray) and got.dtype == np.float64
    np.testing.assert_array_equal(got, want.double().numpy())


def test_the_mpc_calls_each_kind_of_model_in_its_own_way(tiny_run):
    """Numpy models as they are, compiled ones through their numpy entry, eager torch ones
    through ``TorchCandidates``."""
    eager = load_model(tiny_run.out, backend="eager")
    assert isinstance(candidate_model(eager), TorchCandidates)
    compiled = load_model(tiny_run.out, backend="compiled")
    assert candidate_model(compiled).predict_candidates == compiled.numpy_candidates
    oracle = PlantCandidates()
    assert candidate_model(oracle) is oracle


@pytest.mark.parametrize("params", [PARAMS, OTHER_PARAMS])
def test_compiled_physics_candidates_are_the_physics_model(params):
    gen = torch.Generator().manual_seed(0)
    x_hist, u_past = random_history(4, gen)
    x_hist[-1, VEL] = torch.tensor([0.4, -0.3, 0.2])  # moving, with a swinging load
    x_hist[-1, LOAD_POS] += torch.tensor([0.05, -0.04, 0.0])
    plans = random_plans(K, 40, gen, scale=2.0)
    want = PhysicsModel(params).predict_candidates(x_hist, u_past, plans)
    got = CompiledPhysicsModel(params).predict_candidates(x_hist, u_past, plans)
    assert got.shape == (K, 40, 13) and got.dtype == torch.float64
    assert_numpy_entry(CompiledPhysicsModel(params), x_hist, u_past, plans, got)
    torch.testing.assert_close(got, want, rtol=0, atol=1e-9)
    # float32 plans: float32 out (the plans' dtype), computed in float64 inside
    got32 = CompiledPhysicsModel(params).predict_candidates(x_hist, u_past, plans.float())
    assert got32.dtype == torch.float32
    torch.testing.assert_close(got32, want.float(), rtol=1e-6, atol=1e-6)


def test_windows_are_the_eager_models():
    gen = torch.Generator().manual_seed(5)
    x_hist, u_past = random_history(M, gen)
    windows = candidate_windows(x_hist, u_past, random_plans(K, N, gen))
    got = CompiledPhysicsModel(PARAMS).predict_windows(windows)
    torch.testing.assert_close(got, PhysicsModel(PARAMS).predict_windows(windows))
    net = random_network(replace(TINY, architecture=PHYSICS_STEP), PARAMS).double()
    got = CompiledNetworkModel(net, M).predict_windows(windows)
    torch.testing.assert_close(got, NetworkModel(net, M).predict_windows(windows))


# --- networks -------------------------------------------------------------------------------

MODES = [
    {},
    {"slack": False, "relative_positions": False},
    {"normalize": False},
    {"num_layers": 3, "embed_sizes": (12, 10, 9), "head_sizes": (11, 7, 6)},  # the paper's shape
    {"num_layers": 2, "embed_sizes": (12,), "head_sizes": (10, 9)},
]


def random_network(config: ModelConfig, params: VehicleParams, seed: int = 0) -> torch.nn.Module:
    """A float32 network in eval mode with random weights and a non-trivial normalisation."""
    torch.manual_seed(seed)
    net = build(config, params).eval()
    if config.normalize:
        with torch.no_grad():
            net.state_mean.normal_(0.0, 0.3)
            net.state_std.uniform_(0.5, 2.0)
            net.delta_std.uniform_(0.01, 0.1)
            net.input_mean.copy_(torch.tensor([14.0, 0.0, 0.0, 0.0]))
            net.input_std.uniform_(0.5, 2.0)
    return net


def assert_parity(
    net: torch.nn.Module, m: int = M, n: int = N, k: int = K, seed: int = 1, yaw: float = 0.0
):
    """The compiled network's candidates equal the eager network's (a history near hover,
    away from the origin, heading ``yaw`` rad)."""
    gen = torch.Generator().manual_seed(seed)
    x_hist, u_past = random_history(m, gen)
    x_hist[:, POS] += torch.tensor([1.0, -2.0, 0.5])  # away from the origin
    x_hist[:, LOAD_POS] += torch.tensor([1.0, -2.0, 0.5])
    if yaw:
        x_hist = rotate_about_z(x_hist, torch.zeros(m, 6, dtype=x_hist.dtype), yaw)[0]
    plans = random_plans(k, n, gen, scale=1.0)
    want = NetworkModel(net, m).predict_candidates(x_hist, u_past, plans)
    compiled = CompiledNetworkModel(net, m)
    got = compiled.predict_candidates(x_hist, u_past, plans)
    assert got.shape == want.shape == (k, n, 13) and got.dtype == torch.float64
    assert_numpy_entry(compiled, x_hist, u_past, plans, got)
    diff = (got - want).abs().max().item()
    assert diff <= PARITY_TOLERANCE, diff
    torch.testing.assert_close(got[:, :, QUAT].norm(dim=-1), torch.ones(k, n, dtype=got.dtype))
    return diff


@pytest.mark.parametrize("architecture", sorted(MODELS))
@pytest.mark.parametrize("change", MODES)
def test_compiled_network_matches_the_eager_network(architecture, change):
    config = replace(TINY, architecture=architecture, **change)
    assert_parity(random_network(config, PARAMS))


@pytest.mark.parametrize("architecture", sorted(MODELS))
def test_compiled_network_in_the_heading_frame_matches_the_eager_network(architecture):
    config = replace(TINY, architecture=architecture, heading_frame=True)
    net = random_network(config, PARAMS)
    assert_parity(net, yaw=2.4)
    # the frame is the network's: without it the same weights predict something else there
    gen = torch.Generator().manual_seed(1)
    x_hist, u_past = random_history(M, gen)
    x_hist = rotate_about_z(x_hist, torch.zeros(M, 6, dtype=x_hist.dtype), 2.4)[0]
    plans = random_plans(K, N, gen, scale=1.0)
    world = replace(config, heading_frame=False)
    other = random_network(world, PARAMS)
    other.load_state_dict(net.state_dict())
    a = CompiledNetworkModel(net, M).predict_candidates(x_hist, u_past, plans)
    b = CompiledNetworkModel(other, M).predict_candidates(x_hist, u_past, plans)
    assert (a - b).abs().max() > 1e-3


def test_compiled_network_with_absolute_head_matches_the_eager_network():
    assert_parity(random_network(replace(TINY, residual=False), PARAMS))


@pytest.mark.parametrize("params", [PARAMS, OTHER_PARAMS])
@pytest.mark.parametrize("load_estimate", ["difference", "smoothed"])
def test_compiled_physics_step_network_with_constants_and_load_estimates(params, load_estimate):
    config = replace(TINY, architecture=PHYSICS_STEP, load_estimate=load_estimate)
    assert_parity(random_network(config, params), m=12, n=20)


@pytest.mark.parametrize("architecture", sorted(MODELS))
def test_compiled_network_at_the_paper_size(architecture):
    assert_parity(random_network(ModelConfig(architecture=architecture), PARAMS), m=50, n=15)


@pytest.mark.parametrize("size", [s for s in MODEL_SIZES if s != "paper"])
def test_compiled_network_at_every_named_size(size):
    config = ModelConfig.sized(size, architecture=PHYSICS_STEP)
    assert_parity(random_network(config, PARAMS), m=20, n=15)


def test_zero_head_physics_step_network_is_the_physics_model():
    net = random_network(replace(TINY, architecture=PHYSICS_STEP), PARAMS)
    with torch.no_grad():
        net.head.layers[-1].weight.zero_()
        net.head.layers[-1].bias.zero_()
    gen = torch.Generator().manual_seed(2)
    x_hist, u_past = random_history(M, gen)
    plans = random_plans(K, N, gen)
    got = CompiledNetworkModel(net, M).predict_candidates(x_hist, u_past, plans)
    want = PhysicsModel(PARAMS).predict_candidates(x_hist, u_past, plans)
    torch.testing.assert_close(got, want, rtol=0, atol=2e-5)


def test_compiled_network_reuses_and_resizes_its_buffers():
    net = random_network(replace(TINY, architecture=PHYSICS_STEP), PARAMS)
    model = CompiledNetworkModel(net, M)
    eager = NetworkModel(net, M)
    gen = torch.Generator().manual_seed(3)
    for m, k, n in [(M, 5, 4), (M, 5, 7), (M, 13, 4), (4, 13, 4), (M, 5, 4)]:
        x_hist, u_past = random_history(m, gen)
        plans = random_plans(k, n, gen).float()
        got = model.predict_candidates(x_hist, u_past, plans)
        assert got.dtype == torch.float32  # the plans' dtype
        want = eager.predict_candidates(x_hist, u_past, plans)
        torch.testing.assert_close(got, want, rtol=0, atol=PARITY_TOLERANCE)
    first = model.predict_candidates(x_hist, u_past, plans)
    again = model.predict_candidates(x_hist, u_past, plans)
    torch.testing.assert_close(first, again, rtol=0, atol=0)  # a fresh result, not a buffer


def test_compiled_network_refuses_bad_inputs_and_what_it_cannot_run():
    net = random_network(replace(TINY, architecture=PHYSICS_STEP, load_estimate="smoothed"), PARAMS)
    model = CompiledNetworkModel(net, M)
    gen = torch.Generator().manual_seed(4)
    x_hist, u_past = random_history(2, gen)
    with pytest.raises(ValueError, match="M >= 3"):
        model.predict_candidates(x_hist, u_past, random_plans(3, 4, gen))
    with pytest.raises(ValueError, match="predict_candidates"):
        model.predict_candidates(x_hist, u_past[:0], random_plans(3, 4, gen))

    class Other(torch.nn.Module):
        architecture = "my-net"

    with pytest.raises(ValueError, match="'my-net'"):
        CompiledNetworkModel(Other(), M)


# --- the backend choice ---------------------------------------------------------------------


def test_backends_wrap_the_models_and_refuse_the_unknown(tiny_run):
    assert list(PREDICTION_BACKENDS)[0] == "eager"
    physics = load_model("physics", PARAMS, backend="compiled")
    assert isinstance(physics, CompiledPhysicsModel) and isinstance(physics, PredictionModel)
    assert isinstance(load_model("physics", PARAMS), PhysicsModel)  # the default is eager
    network = load_model(tiny_run.out, backend="compiled")
    assert isinstance(network, CompiledNetworkModel) and isinstance(network, PredictionModel)
    eager = load_model(tiny_run.out)
    assert isinstance(eager, NetworkModel) and network.name == eager.name
    assert network.history == eager.history
    with pytest.raises(ValueError, match="unknown prediction backend 'fast'"):
        load_model("physics", backend="fast")
    with pytest.raises(ValueError, match="PhysicsModel or a NetworkModel"):
        with_backend(object(), "compiled")
    assert math.isfinite(
        network.predict_candidates(
            *random_history(network.history, torch.Generator().manual_seed(0)),
            random_plans(3, 4, torch.Generator().manual_seed(0)),
        )
        .abs()
        .max()
        .item()
    )


# --- the GPU backend (its parity runs where torch sees a GPU) ---------------------------------

GPU = pytest.mark.skipif(not torch.cuda.is_available(), reason="torch sees no GPU here")
GPU_MODES = [
    ("lstm-attention", {}),
    (PHYSICS_STEP, {}),
    (PHYSICS_STEP, {"load_estimate": "smoothed", "constants": "window", "constants_input": True}),
    (PHYSICS_STEP, {"num_layers": 3, "embed_sizes": (12, 10, 9), "head_sizes": (11, 7, 6)}),
]


def test_cuda_backend_without_a_gpu_is_refused_by_name(monkeypatch, run_cli, tmp_path):
    from slungload.lab.bench.mpc import benchmark_mpc

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(ValueError, match="cuda backend runs on a GPU.*sees none"):
        with_backend(PhysicsModel(PARAMS), "cuda")
    with pytest.raises(ValueError, match="cuda backend runs on a GPU.*sees none"):
        benchmark_mpc(samples=(3,), horizons=(4,), backends=("compiled", "cuda"))
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)  # refused before the device
    with pytest.raises(ValueError, match="constants='window' reads its constants on the host"):
        with_backend(PhysicsModel(PARAMS, constants="window"), "cuda")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    code, _, err = run_cli(
        "control", "--maneuvers", "roll_35", "--seeds", "100", "--samples", "4", "--horizon",
        "5", "--steps", "8", "--out", tmp_path / "ctl", "--quiet", "--backend", "cuda",
    )  # fmt: skip
    assert code == 2 and "cuda backend runs on a GPU" in err and "Traceback" not in err
    assert not (tmp_path / "ctl" / "results.json").exists()


def test_graphed_model_keeps_a_few_shapes_and_drops_the_least_recently_used(monkeypatch):
    from slungload.deploy import gpu

    captured = []

    def fake_capture(self, x_hist, u_past, plans):  # no GPU here: a graph that replays eager
        captured.append(plans.shape[0])
        inputs = [t.clone() for t in (x_hist, u_past, plans)]
        states = torch.zeros(*plans.shape[:2], 13, dtype=plans.dtype)

        class Replay:
            def replay(self):
                states.copy_(PhysicsModel(PARAMS).predict_candidates(*inputs))

        return gpu._Graph(*inputs, Replay(), states)

    monkeypatch.setattr(gpu.GraphedModel, "_capture", fake_capture)
    model = gpu.GraphedModel(PhysicsModel(PARAMS))
    gen = torch.Generator().manual_seed(8)
    x_hist, u_past = random_history(4, gen)
    for k in [*range(1, gpu.MAX_GRAPHS + 1), 1, gpu.MAX_GRAPHS + 1, 2]:
        plans = random_plans(k, 3, gen)
        got = model.predict_candidates(x_hist, u_past, plans)
        want = PhysicsModel(PARAMS).predict_candidates(x_hist, u_past, plans)
        torch.testing.assert_close(got, want, rtol=0, atol=0)  # the new inputs, replayed
    # K = 1 replayed from its graph; K = MAX + 1 then pushed out K = 2, the least recently used
    assert captured == [*range(1, gpu.MAX_GRAPHS + 1), gpu.MAX_GRAPHS + 1, 2]
    assert len(model._graphs) == gpu.MAX_GRAPHS
    model.prepare(4, 2, 3)  # held: nothing captured
    model.prepare(6, 5, 7)  # the MPC's shapes, float64, captured before any call
    assert captured[-2:] == [2, 5] and (6, 5, 7, *(torch.float64,) * 3) in model._graphs


@GPU
@pytest.mark.parametrize("params", [PARAMS, OTHER_PARAMS])
def test_cuda_physics_is_the_physics_model(params):
    gen = torch.Generator().manual_seed(6)
    x_hist, u_past = random_history(4, gen)
    eager = PhysicsModel(params)
    gpu = with_backend(eager, "cuda")
    for _ in range(2):  # the second call replays the first one's graph on new inputs
        x_hist[-1, VEL] = torch.randn(3, generator=gen, dtype=torch.float64)
        plans = random_plans(K, 40, gen, scale=2.0)
        got = gpu.predict_candidates(x_hist, u_past, plans)
        assert got.device.type == "cpu" and got.dtype == torch.float64
        torch.testing.assert_close(got, eager.predict_candidates(x_hist, u_past, plans),
                                   rtol=0, atol=1e-9)  # fmt: skip


@GPU
@pytest.mark.parametrize(("architecture", "change"), GPU_MODES)
def test_cuda_network_matches_the_eager_network_and_leaves_it_on_the_cpu(architecture, change):
    net = random_network(replace(TINY, architecture=architecture, **change), PARAMS)
    eager = NetworkModel(net, 50)
    gpu = with_backend(eager, "cuda")
    gen = torch.Generator().manual_seed(7)
    for k, n in [(K, 15), (K, 15), (5, 7)]:  # a replay on new inputs, then a second graph
        x_hist, u_past = random_history(50, gen)
        plans = random_plans(k, n, gen, scale=1.0)
        got = gpu.predict_candidates(x_hist, u_past, plans)
        want = eager.predict_candidates(x_hist, u_past, plans)
        assert got.shape == (k, n, 13) and got.device.type == "cpu"
        assert got.dtype == torch.float64
        assert (got - want).abs().max().item() <= PARITY_TOLERANCE
    assert next(net.parameters()).device.type == "cpu"  # the eager model stays where it was
    assert next(gpu.model.net.parameters()).device.type == "cuda"


def fly_on(run_cli, out, backend: str, samples: int, steps: int) -> None:
    """``control`` on ``backend``: every flight to the end, the backend in results.json."""
    code, _, err = run_cli(
        "control", "--maneuvers", "roll_35", "--seeds", "100", "--samples", str(samples),
        "--horizon", "5", "--steps", str(steps), "--out", out, "--quiet", "--backend", backend,
    )  # fmt: skip
    assert code == 0, err
    results = json.loads((out / "results.json").read_text())
    assert results["settings"]["backend"] == backend
    assert all(r["completed"] for r in results["rows"])


@GPU
def test_control_flies_on_the_cuda_backend(run_cli, tmp_path):
    fly_on(run_cli, tmp_path / "ctl", "cuda", samples=64, steps=40)


@GPU
def test_mpc_benchmark_times_the_gpu_beside_the_cpu():
    from slungload.lab.bench.mpc import benchmark_mpc

    config = replace(TINY, architecture=PHYSICS_STEP)
    result = benchmark_mpc(samples=(3,), horizons=(4,), calls=2, seconds=0.01, model_config=config,
                           backends=("cuda", "compiled"))  # fmt: skip
    assert result.reference == "compiled"  # the first of TIMED's order
    rows = {(r.model, r.backend): r for r in result.rows}
    assert set(rows) == {(m, b) for m in ("physics", "physics-step network")
                         for b in ("compiled", "cuda")}  # fmt: skip
    assert rows[("physics", "cuda")].max_abs_diff <= 1e-9
    assert rows[("physics-step network", "cuda")].max_abs_diff <= PARITY_TOLERANCE


def test_control_flies_on_the_compiled_backend(run_cli, tmp_path):
    out = tmp_path / "ctl"
    fly_on(run_cli, out, "compiled", samples=4, steps=8)
    assert "prediction backend compiled" in (out / "report.md").read_text()
    with pytest.raises(SystemExit):  # argparse: invalid choice
        run_cli("control", "--backend", "fast", "--out", tmp_path / "x")


def test_mpc_benchmark_times_every_backend_on_the_same_calls():
    from slungload.lab.bench.mpc import MIN_CALLS, benchmark_mpc

    config = replace(TINY, architecture=PHYSICS_STEP)
    result = benchmark_mpc(samples=(3,), horizons=(4,), calls=2, seconds=0.01, model_config=config)
    rows = {(r.model, r.backend): r for r in result.rows}
    gpu = (
        {("physics", "cuda"), ("physics-step network", "cuda")}
        if torch.cuda.is_available()
        else set()
    )
    assert set(rows) == gpu | {
        ("physics", "eager"), ("physics", "compiled"), ("physics-step network", "eager"),
        ("physics-step network", "compiled"), ("physics-step network", "onnxruntime"),
    }  # fmt: skip
    for (model, _), row in rows.items():
        assert (row.samples, row.horizon, row.calls) == (3, 4, MIN_CALLS)
        assert row.median_ms > 0 and row.p99_ms >= row.median_ms and row.cpu_median_ms > 0
        assert row.max_abs_diff <= (1e-9 if model == "physics" else PARITY_TOLERANCE)
    assert rows[("physics", "eager")].speedup == 1.0
    table = result.markdown()
    assert "| physics-step network | compiled | 4 | 3 | 5 |" in table
    assert "load average (1 min)" in table and "custom-size" in table
    assert ("No cuda row" in table) == (not torch.cuda.is_available())


def test_mpc_benchmark_times_the_backends_asked_for_against_the_first():
    from slungload.lab.bench.mpc import benchmark_mpc

    config = replace(TINY, architecture=PHYSICS_STEP)
    result = benchmark_mpc(samples=(3,), horizons=(4,), calls=2, seconds=0.01, model_config=config,
                           backends=("onnxruntime", "compiled"))  # fmt: skip
    assert result.reference == "compiled"
    rows = {(r.model, r.backend): r for r in result.rows}
    assert set(rows) == {("physics", "compiled"), ("physics-step network", "compiled"),
                         ("physics-step network", "onnxruntime")}  # fmt: skip
    assert rows[("physics-step network", "compiled")].speedup == 1.0
    assert rows[("physics-step network", "onnxruntime")].max_abs_diff <= PARITY_TOLERANCE
    table = result.markdown()
    assert "speed-up against compiled" in table
    assert "| physics-step network | compiled | 4 | 3 | 5 |" in table and "| - |" in table
    with pytest.raises(ValueError, match="unknown backends to time \\['fast'\\]; known: .*'cuda'"):
        benchmark_mpc(samples=(3,), horizons=(4,), backends=("compiled", "fast"))


def test_benchmark_backends_are_checked_by_name(run_cli, tmp_path):
    code, _, err = run_cli("benchmark", "--mpc", "--quick", "--backends", "compiled,fast")
    assert code == 2 and "unknown backends to time ['fast']" in err and "Traceback" not in err
    code, _, err = run_cli("benchmark", "--backends", "compiled", "--no-train")
    assert code == 2 and "--backends is for --mpc" in err


def test_benchmark_mpc_command(run_cli, tmp_path):
    out = tmp_path / "mpc.md"
    code, stdout, err = run_cli(
        "benchmark", "--mpc", "--quick", "--samples", "3", "--horizons", "4", "--size", "tiny",
        "--out", out,
    )  # fmt: skip
    assert code == 0, err
    assert "random tiny-size physics-step network" in out.read_text()
    assert "| physics | compiled | 4 | 3 |" in stdout
    code, _, err = run_cli("benchmark", "--size", "tiny")
    assert code != 0 and "--size is for --mpc" in err
