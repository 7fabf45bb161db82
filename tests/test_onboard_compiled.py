"""The onboard path on numpy + Numba: a network's fold (or the discrete model) exported as an
archive (``.mpc.npz``) equal to the eager model and to the compiled backend bit for bit (the
same rollouts), its sidecar checks, the loaders, and the onboard MPC flying it without torch."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from test_onboard import (
    ARCHITECTURES,
    BLOCK,
    LIMITS,
    PARAMS,
    WINDOW,
    run_example_blocked,
    small_predictor,
)

from slungload.control.mpc import SamplingMPC
from slungload.control.mppi import MPCConfig, MPPIController, ReferenceAhead
from slungload.deploy.backends import load_exported, load_model
from slungload.deploy.candidates import candidate_inputs, export_for_mpc, hover_inputs
from slungload.deploy.compiled import NetworkColumns, PhysicsColumns, with_backend
from slungload.deploy.compiled.archive import load_columns
from slungload.deploy.predictor import PARITY_TOLERANCE
from slungload.deploy.sidecar import OnnxModelError, sha256, sidecar_path
from slungload.fileio import read_npz, write_npz
from slungload.models.prediction import NetworkModel, PhysicsModel

# the onboard install has Numba for this path: block the rest
BLOCK_BUT_NUMBA = BLOCK.replace('"numba", ', "")


@pytest.fixture(scope="module")
def compiled(tmp_path_factory):
    """Each architecture's small network exported in the compiled format."""
    folder = tmp_path_factory.mktemp("mpc_npz")
    out = {}
    for arch in ARCHITECTURES:
        predictor = small_predictor(arch)
        result = export_for_mpc(predictor, folder, horizon=WINDOW.horizon, format="compiled")
        assert result.model.name == "model.mpc.npz" and result.opset is None
        assert result.max_abs_diff <= PARITY_TOLERANCE and "K and N dynamic" in result.summary()
        out[arch] = (predictor, result.model)
        folder = tmp_path_factory.mktemp("mpc_npz")
    return out


def eager_candidates(predictor, x_hist, u_past, plans) -> np.ndarray:
    eager = NetworkModel(predictor.model, WINDOW.history)
    return eager.predict_candidates(*(torch.from_numpy(a) for a in (x_hist, u_past, plans))).numpy()


@pytest.mark.parametrize("architecture", ARCHITECTURES)
@pytest.mark.parametrize("k, n", [(1, 6), (5, 3), (64, 11)])
def test_the_compiled_file_equals_the_eager_model_at_any_k_and_n(compiled, architecture, k, n):
    predictor, path = compiled[architecture]
    x_hist, u_past, plans = (a.astype(np.float64) for a in candidate_inputs(predictor, n, k))
    model = load_columns(path)
    assert isinstance(model, NetworkColumns) and model.history == WINDOW.history
    got = model.predict_candidates(x_hist, u_past, plans)
    assert got.shape == (k, n, 13) and got.dtype == np.float64
    assert np.abs(got - eager_candidates(predictor, x_hist, u_past, plans)).max() <= 1e-4
    # the same rollouts as the compiled backend: the same numbers, not merely close ones
    backend = with_backend(NetworkModel(predictor.model, WINDOW.history), "compiled")
    np.testing.assert_array_equal(got, backend.numpy_candidates(x_hist, u_past, plans))


@pytest.mark.parametrize(
    "options",
    [
        dict(heading_frame=True),
        dict(load_estimate="smoothed"),
        dict(residual=False),
    ],
)
def test_every_model_mode_exports_compiled(tmp_path, options):
    """The heading frame, the smoothed load estimate and an absolute head survive the file:
    equal to eager on a history heading far from x."""
    from slungload.state import rotate_about_z

    arch = "lstm-attention" if "residual" in options else "physics-step"
    predictor = small_predictor(arch, **options)
    result = export_for_mpc(predictor, tmp_path, horizon=WINDOW.horizon, format="compiled")
    x_hist, u_past, plans = (a.astype(np.float64) for a in candidate_inputs(predictor, 6, 16))
    x_t = torch.from_numpy(x_hist)
    x_hist = rotate_about_z(x_t, torch.zeros(*x_t.shape[:-1], 6, dtype=x_t.dtype), 2.0)[0].numpy()
    got = load_columns(result.model).predict_candidates(x_hist, u_past, plans)
    assert np.abs(got - eager_candidates(predictor, x_hist, u_past, plans)).max() <= 1e-4


@pytest.mark.parametrize("seen", [False, True])
def test_the_archive_keeps_every_field_of_the_fold(seen):
    """A network on its window's constants (seen by it or not: the constants' columns and the
    reference they are measured against) comes back from the archive's arrays field by field
    (its predictions: ``test_batched``, on the same rollouts)."""
    from slungload.deploy.compiled.archive import arrays, columns_of, folded_record
    from slungload.deploy.compiled.fold import fold

    predictor = small_predictor("physics-step", constants="window", constants_input=seen)
    folded = fold(predictor.model)
    meta = {"architecture": "physics-step", "history": 8, "folded": folded_record(folded)}
    back = columns_of(arrays(folded, folded.vehicle), meta).folded
    assert back.constants == "window" and back.reference == folded.reference
    assert (back.embed_constants.shape[1] > 0) == seen
    for name, a, b in zip(folded._fields, folded, back, strict=True):
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b, err_msg=name)
        elif name in ("embed", "head"):
            for (wa, ba), (wb, bb) in zip(a, b, strict=True):
                np.testing.assert_array_equal(wa, wb)
                np.testing.assert_array_equal(ba, bb)
        else:
            assert a == b, name


@pytest.mark.parametrize("constants", ["dataset", "window"])
def test_the_physics_model_exports_compiled(tmp_path, constants):
    """The discrete model as a compiled file: float64, equal to PhysicsModel to round-off."""
    params = PARAMS
    result = export_for_mpc("physics", tmp_path, horizon=5, params=params, format="compiled")
    if constants == "window":  # the sidecar names f's constants; the window's estimate then
        side = sidecar_path(result.model)
        side.write_text(json.dumps({**json.loads(side.read_text()), "constants": constants}))
    model = load_columns(result.model)
    assert isinstance(model, PhysicsColumns) and model.params == params
    x = np.repeat(hover_inputs(params, 5, 1)[0][-1:].astype(np.float64), 20, axis=0)
    x[:, 0] += 0.01 * np.arange(20)  # a history the window estimate can read
    u_past = np.tile([[(params.mass_quad + params.mass_load) * params.gravity, 0, 0, 0]], (19, 1))
    plans = hover_inputs(params, 7, 9)[2].astype(np.float64)  # any N: 7
    want = PhysicsModel(params, constants=constants).predict_candidates(
        *(torch.from_numpy(a) for a in (x, u_past, plans))
    )
    assert np.abs(model.predict_candidates(x, u_past, plans) - want.numpy()).max() < 1e-9


def test_the_loaders_take_the_compiled_file_and_refuse_what_it_cannot_do(compiled, tiny_run):
    path = compiled["physics-step"][1]
    assert isinstance(load_model(path, backend="compiled"), NetworkColumns)
    assert isinstance(load_exported(path), NetworkColumns)
    with pytest.raises(ValueError, match="runs on the compiled backend, not 'onnx'"):
        load_model(path, backend="onnx")
    with pytest.raises(ValueError, match="takes no params or constants"):
        load_model(path, PARAMS, backend="compiled")
    with pytest.raises(ValueError, match="not an exported MPC model"):
        load_exported(tiny_run.out)
    with pytest.raises(ValueError, match="a compiled model is a .npz file"):
        export_for_mpc("physics", path.with_suffix(".onnx"), horizon=5, format="compiled")
    with pytest.raises(ValueError, match="model.mpc.onnx's sidecar model.mpc.json would overwrite"):
        export_for_mpc("physics", path.with_suffix(".onnx"), horizon=5)  # beside model.mpc.npz
    with pytest.raises(ValueError, match="unknown format 'tflite'"):
        export_for_mpc("physics", path.parent, horizon=5, format="tflite")


def _copy(source, folder):
    path = folder / source.name
    path.write_bytes(source.read_bytes())
    sidecar_path(path).write_bytes(sidecar_path(source).read_bytes())
    return path


def test_a_damaged_or_mismatched_compiled_file_is_refused_by_name(compiled, tmp_path):
    source = compiled["physics-step"][1]
    path = _copy(source, tmp_path)
    path.write_bytes(path.read_bytes()[:-9] + b"123456789")
    with pytest.raises(OnnxModelError, match="does not match its sidecar"):
        load_columns(path)
    path = _copy(source, tmp_path)
    sidecar_path(path).unlink()
    with pytest.raises(OnnxModelError, match="sidecar model.mpc.json is missing"):
        load_columns(path)
    # an onnx sidecar beside it
    path = _copy(source, tmp_path)
    side = sidecar_path(path)
    side.write_text(json.dumps({**json.loads(side.read_text()), "format": "slungload-onnx-mpc"}))
    with pytest.raises(OnnxModelError, match="not a slungload compiled MPC sidecar"):
        load_columns(path)
    # arrays that do not fit together, with a checksum that matches them
    path = _copy(source, tmp_path)
    data = read_npz(path)
    data["att_w"] = data["att_w"][:, :-1]
    write_npz(path, data)
    side = sidecar_path(path)
    side.write_text(json.dumps({**json.loads(side.read_text()), "model_sha256": sha256(path)}))
    with pytest.raises(OnnxModelError, match=r"model.mpc.npz: a damaged .*'att_w'"):
        load_columns(path)


def test_the_onboard_mpc_on_the_compiled_file_plans_as_the_compiled_backend(compiled):
    """The same samples, the same rollouts: the onboard controller's plans are the torch MPC's
    over the compiled backend, exactly."""
    predictor, path = compiled["physics-step"]
    cfg = MPCConfig(samples=32, horizon=7, knots=3, seed=5)
    onboard = MPPIController.from_file(path, LIMITS, cfg)
    assert onboard.cfg.horizon == 7  # a compiled file keeps the config's N
    work = onboard.model._work  # prepared when built: compiled, its arrays made for K
    assert (work.shared, work.k) == (WINDOW.history - 1, 32)
    backend = with_backend(NetworkModel(predictor.model, WINDOW.history), "compiled")
    torch_mpc = SamplingMPC(backend, LIMITS, cfg, PARAMS)
    x_hist = candidate_inputs(predictor, 7, 1)[0].astype(np.float64)
    ref = ReferenceAhead(
        np.tile(x_hist[-1, :3] + [0.3, 0, 0], (7, 1)), np.zeros((7, 3)), np.zeros(7)
    )
    for x in x_hist:
        onboard.step(x, ref)
        torch_mpc.core.step(x, ref)
        np.testing.assert_array_equal(onboard.plan, torch_mpc.core.plan)
    assert onboard.stats.fallback_steps == 0


def test_the_example_loop_flies_compiled_files_without_torch(compiled, tmp_path):
    vehicle = export_for_mpc("physics", tmp_path / "vehicle.mpc.npz", horizon=2, format="compiled")
    argv = [str(compiled["physics-step"][1]), "--vehicle", str(vehicle.model), "--samples", "16",
            "--steps", "12"]  # fmt: skip
    out = run_example_blocked(BLOCK_BUT_NUMBA, argv, ("torch", "onnxruntime"))
    assert "12 steps, K = 16, N = 15: vehicle RMSE" in out and "[]" in out


def test_export_command_writes_the_compiled_format(run_cli, tiny_run, tmp_path):
    code, out, err = run_cli(
        "export", tiny_run.out, "--for-mpc", "--format", "compiled", "--out", tmp_path
    )
    assert code == 0, err
    (model,) = tmp_path.glob("*.mpc.npz")
    assert "compiled MPC model (numpy + Numba)" in out and load_columns(model).horizon is None
    code, out, err = run_cli("export", tiny_run.out, "--format", "compiled", "--out", tmp_path)
    assert code == 2 and "add --for-mpc" in err
