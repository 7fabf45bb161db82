"""The onboard path: the MPC's candidates graph (encoder once, decoder batched over a dynamic K)
equal to ``forward_candidates``, its sidecar checks, the onboard MPC's plans equal to the torch
MPC's for the same samples, and a controller that runs with numpy + onnxruntime alone."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from flights import physics_flight

from slungload.config import ModelConfig, VehicleParams, WindowConfig
from slungload.control.mpc import SamplingMPC, candidate_model
from slungload.control.mppi import InputLimits, MPCConfig, MPPIController, ReferenceAhead
from slungload.data.windows import make_windows
from slungload.deploy.backends import load_model
from slungload.deploy.candidates import candidate_inputs, export_for_mpc, hover_inputs
from slungload.deploy.onboard import OnnxCandidateModel
from slungload.deploy.predictor import PARITY_TOLERANCE, Predictor
from slungload.deploy.sidecar import OnnxModelError, sidecar_path
from slungload.models import build
from slungload.models.prediction import NetworkModel, PhysicsModel

torch.set_num_threads(1)
PARAMS = VehicleParams()
WINDOW = WindowConfig(history=8, horizon=6)
HOVER_T = (PARAMS.mass_quad + PARAMS.mass_load) * PARAMS.gravity
LIMITS = InputLimits(0.3 * HOVER_T, 30.0, 4.0)
SMALL = dict(embed_sizes=(32, 48), hidden_size=12, num_layers=2, head_sizes=(32, 24, 16))
ARCHITECTURES = ["lstm-attention", "physics-step"]


def small_predictor(architecture: str, **options) -> Predictor:
    """A small network of ``architecture``, random weights, normalisation fitted on windows of
    physics flights."""
    windows = make_windows([physics_flight(f"f{i}", i, 80) for i in range(2)], WINDOW)
    torch.manual_seed(1)
    net = build(ModelConfig(architecture=architecture, **SMALL, **options), PARAMS)
    net.fit_normalization(windows.states, windows.inputs, origin_step=WINDOW.history - 1)
    return Predictor(net.eval(), WINDOW, PARAMS, "no-physics")


@pytest.fixture(scope="module")
def exported(tmp_path_factory) -> dict[str, tuple[Predictor, Path]]:
    folder = tmp_path_factory.mktemp("mpc_onnx")
    out = {}
    for arch in ARCHITECTURES:
        predictor = small_predictor(arch)
        result = export_for_mpc(predictor, folder / f"{arch}.mpc.onnx", horizon=WINDOW.horizon)
        assert result.max_abs_diff <= PARITY_TOLERANCE
        out[arch] = (predictor, result.model)
    return out


@pytest.mark.parametrize("architecture", ARCHITECTURES)
@pytest.mark.parametrize("k", [1, 5, 64])
def test_the_candidates_graph_equals_forward_candidates(exported, architecture, k):
    predictor, path = exported[architecture]
    x_hist, u_past, plans = (a.astype(np.float64) for a in candidate_inputs(predictor, 6, k))
    onboard = OnnxCandidateModel(path)
    eager = NetworkModel(predictor.model, WINDOW.history)
    want = eager.predict_candidates(*(torch.from_numpy(a) for a in (x_hist, u_past, plans)))
    got = onboard.predict_candidates(x_hist, u_past, plans)
    assert got.shape == (k, 6, 13) and got.dtype == np.float64
    assert np.abs(got - want.numpy()).max() <= PARITY_TOLERANCE


def test_the_smoothed_load_estimate_exports_too(tmp_path):
    predictor = small_predictor("physics-step", load_estimate="smoothed")
    result = export_for_mpc(predictor, tmp_path, horizon=4)
    assert result.model.name == "model-n4.mpc.onnx" and result.max_abs_diff <= PARITY_TOLERANCE


@pytest.mark.parametrize("architecture", ARCHITECTURES)
def test_the_heading_frame_exports_too(tmp_path, architecture):
    """A network that sees its windows in the heading frame exports with the turn in the
    graph: equal to forward_candidates on a history heading far from x."""
    from slungload.state import rotate_about_z

    predictor = small_predictor(architecture, heading_frame=True)
    result = export_for_mpc(predictor, tmp_path, horizon=WINDOW.horizon)
    assert result.max_abs_diff <= PARITY_TOLERANCE
    x_hist, u_past, plans = (a.astype(np.float64) for a in candidate_inputs(predictor, 6, 16))
    x_t = torch.from_numpy(x_hist)
    x_hist = rotate_about_z(x_t, torch.zeros(*x_t.shape[:-1], 6, dtype=x_t.dtype), 2.0)[0].numpy()
    eager = NetworkModel(predictor.model, WINDOW.history)
    want = eager.predict_candidates(*(torch.from_numpy(a) for a in (x_hist, u_past, plans)))
    got = OnnxCandidateModel(result.model).predict_candidates(x_hist, u_past, plans)
    assert np.abs(got - want.numpy()).max() <= PARITY_TOLERANCE


@pytest.mark.parametrize("architecture", ARCHITECTURES)
def test_the_onboard_mpc_plans_as_the_torch_mpc(exported, architecture):
    """Same seed, so the same samples: the plans differ only by the float32 rounding of the
    two runtimes, through the weights."""
    predictor, path = exported[architecture]
    cfg = MPCConfig(samples=48, horizon=WINDOW.horizon, knots=3, seed=7)
    torch_mpc = SamplingMPC(NetworkModel(predictor.model, WINDOW.history), LIMITS, cfg, PARAMS)
    onboard = MPPIController.from_file(path, LIMITS, cfg)
    x_hist, _, _ = candidate_inputs(predictor, WINDOW.horizon, 1)
    ref = ReferenceAhead(
        np.tile(x_hist[-1, :3] + [0.2, 0.0, 0.1], (6, 1)), np.zeros((6, 3)), np.zeros(6)
    )
    for x in x_hist.astype(np.float64):  # the history's states as successive measurements
        a = torch_mpc.core.step(x, ref)
        b = onboard.step(x, ref)
        np.testing.assert_allclose(onboard.plan, torch_mpc.plan, rtol=0, atol=1e-5)
        assert abs(a.thrust - b.thrust) <= 1e-5 and np.abs(a.rates - b.rates).max() <= 1e-5
    assert onboard.stats.fallback_steps == torch_mpc.stats.fallback_steps == 0


def test_sidecar_describes_the_graph_and_the_vehicle(exported):
    _, path = exported["physics-step"]
    meta = json.loads(sidecar_path(path).read_text())
    assert meta["horizon"] == 6 and meta["history"] == 8
    assert meta["inputs"][2] == {"name": "plans", "shape": ["candidates", 6, 4], "dtype": "float32"}
    assert meta["layout"]["state_columns"][6:10] == ["qw", "qx", "qy", "qz"]
    assert meta["params"]["cable_length"] == PARAMS.cable_length
    assert meta["architecture"] == "physics-step"


@pytest.mark.parametrize(
    ("tamper", "message"),
    [
        (lambda p: p.write_bytes(p.read_bytes() + b"\0"), "checksum differs"),
        (lambda p: sidecar_path(p).unlink(), "sidecar .* is missing"),
        (lambda p: _edit(p, format_version=99), "format version 99"),
        (lambda p: _edit(p, params=None), "vehicle constants"),
    ],
)
def test_a_model_that_disagrees_with_its_sidecar_is_refused(exported, tmp_path, tamper, message):
    _, source = exported["lstm-attention"]
    path = tmp_path / source.name
    path.write_bytes(source.read_bytes())
    sidecar_path(path).write_bytes(sidecar_path(source).read_bytes())
    tamper(path)
    with pytest.raises(OnnxModelError, match=message):
        OnnxCandidateModel(path)


def _edit(path: Path, **changes) -> None:
    side = sidecar_path(path)
    side.write_text(json.dumps({**json.loads(side.read_text()), **changes}))


def test_wrong_shapes_are_refused(exported):
    model = OnnxCandidateModel(exported["lstm-attention"][1])
    x, u = np.zeros((8, 13)), np.zeros((7, 4))
    with pytest.raises(ValueError, match=r"plans \(K, 6, 4\)"):
        model.predict_candidates(x, u, np.zeros((3, 5, 4)))
    with pytest.raises(ValueError, match=r"x_hist \(8, 13\)"):
        model.predict_candidates(x[1:], u, np.zeros((3, 6, 4)))


def test_the_onboard_controller_runs_without_torch(exported):
    code = (
        "import sys\n"
        "import numpy as np\n"
        "from slungload.control.mppi import InputLimits, MPCConfig, MPPIController, "
        "ReferenceAhead\n"
        f"mpc = MPPIController.from_file({str(exported['physics-step'][1])!r}, "
        "InputLimits(4.0, 30.0, 4.0), MPCConfig(samples=16, knots=3))\n"
        "x = np.array([0, 0, 1.5, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0.8])\n"
        "ref = ReferenceAhead(np.tile(x[:3], (6, 1)), np.zeros((6, 3)), np.zeros(6))\n"
        "c = [mpc.step(x, ref) for _ in range(3)][-1]\n"
        "assert np.isfinite(c.thrust) and mpc.stats.fallback_steps == 0, mpc.stats\n"
        "assert 'torch' not in sys.modules and 'lightning' not in sys.modules\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]


def test_export_command_for_the_mpc(run_cli, tiny_run, tmp_path):
    code, out, err = run_cli("export", tiny_run.out, "--for-mpc", "--out", tmp_path)
    assert code == 0, err
    (model,) = tmp_path.glob("*.mpc.onnx")
    assert model.name.endswith("-n15.mpc.onnx") and "MPC candidates graph" in out
    assert OnnxCandidateModel(model).horizon == 15


# --- the example loop (examples/onboard_loop.py), small configurations -----------------------

EXAMPLE = Path(__file__).parents[1] / "examples" / "onboard_loop.py"


@pytest.fixture(scope="module")
def physics_files(tmp_path_factory) -> tuple[Path, Path]:
    """The physics model exported for the MPC (N = 10) and as the example's vehicle (N = 2)."""
    folder = tmp_path_factory.mktemp("physics")
    mpc = export_for_mpc("physics", folder / "physics.mpc.onnx", horizon=10).model
    vehicle = export_for_mpc("physics", folder / "vehicle.mpc.onnx", horizon=2).model
    return mpc, vehicle


# What the onboard install leaves out: the loop must run without any of it.
BLOCK = """
import importlib.abc, sys
class Blocked(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in ("torch", "lightning", "mujoco", "roma", "numba", "matplotlib"):
            raise ImportError(f"{name} is not in the onboard install")
sys.meta_path.insert(0, Blocked())
"""


def run_example_blocked(block: str, argv: list[str], absent: tuple[str, ...]) -> str:
    """The example loop in a fresh interpreter with ``block`` installed first; its output,
    ending in the sorted list of the ``absent`` packages it imported anyway."""
    code = block + (
        f"import runpy\nsys.argv = {['onboard_loop.py', *argv]!r}\n"
        f"runpy.run_path({str(EXAMPLE)!r}, run_name='__main__')\n"
        f"print(sorted(m for m in sys.modules if m.split('.')[0] in {absent!r}))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


def test_the_example_loop_runs_on_an_exported_model_without_torch(exported, physics_files):
    model = exported["physics-step"][1]
    argv = [str(model), "--vehicle", str(physics_files[1]), "--samples", "16", "--steps", "12"]
    out = run_example_blocked(BLOCK, argv, ("torch",))
    assert "12 steps, K = 16, N = 6: vehicle RMSE" in out and "[]" in out


def test_the_example_loop_tracks_with_the_physics_model(physics_files):
    spec = importlib.util.spec_from_file_location("onboard_loop", EXAMPLE)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    mpc, vehicle = physics_files
    rmse = example.main([str(mpc), "--vehicle", str(vehicle), "--samples", "32", "--steps", "60"])
    assert rmse < 0.1  # m: the frames round trip (NED/FRD and back) is right, or it would crash


def test_the_physics_model_exports_too_and_flies_onboard(tmp_path):
    """The discrete model (M = 2) as a candidates graph: equal to PhysicsModel (float64) to
    float32 rounding, and the onboard MPC over it plans as the torch MPC over PhysicsModel."""
    result = export_for_mpc("physics", tmp_path, horizon=5, params=PARAMS)
    assert result.model.name == "physics-n5.mpc.onnx" and result.history == 2
    onboard = OnnxCandidateModel(result.model)
    x_hist, u_past, plans = (a.astype(np.float64) for a in hover_inputs(PARAMS, 5, 32))
    want = PhysicsModel(PARAMS).predict_candidates(
        *(torch.from_numpy(a) for a in (x_hist, u_past, plans))
    )
    assert np.abs(onboard.predict_candidates(x_hist, u_past, plans) - want.numpy()).max() < 1e-4
    cfg = MPCConfig(samples=32, horizon=5, knots=3, seed=3)
    torch_mpc = SamplingMPC(PhysicsModel(PARAMS), LIMITS, cfg, PARAMS)
    onboard_mpc = MPPIController.from_file(result.model, LIMITS, cfg)
    target = np.tile(x_hist[-1, :3] + [0.2, 0, 0], (5, 1))
    ref = ReferenceAhead(target, np.zeros((5, 3)), np.zeros(5))
    for x in (x_hist[0], x_hist[1], x_hist[1]):
        torch_mpc.core.step(x, ref)
        onboard_mpc.step(x, ref)
        np.testing.assert_allclose(onboard_mpc.plan, torch_mpc.plan, rtol=0, atol=1e-5)


def test_one_loader_for_every_backend_onnx_included(physics_files, tiny_run):
    """``load_model`` gives the onnx backend's numpy model (the MPC takes it as it is) and
    refuses what that backend cannot do, naming why; the torch backends as before."""
    mpc_file, _ = physics_files
    model = load_model(mpc_file, backend="onnx")
    assert isinstance(model, OnnxCandidateModel) and candidate_model(model) is model
    limits = InputLimits(4.0, 30.0, 4.0)
    assert SamplingMPC(model, limits, MPCConfig(samples=8, horizon=10)).core.model is model
    with pytest.raises(ValueError, match="takes no params or constants"):
        load_model(mpc_file, PARAMS, backend="onnx")
    with pytest.raises(ValueError, match="export it first"):
        load_model(tiny_run.out, backend="onnx")
    with pytest.raises(ValueError, match="unknown prediction backend 'tensorrt'"):
        load_model(mpc_file, backend="tensorrt")
