"""ONNX export: parity with the eager network on physics windows, sidecar checks, runtime path."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from flights import predict_args
from test_onboard import BLOCK

import slungload.deploy.onnx as onnx_module
from slungload.config import WindowConfig
from slungload.data.windows import make_windows
from slungload.deploy.onboard import OnnxPredictor
from slungload.deploy.onnx import export
from slungload.deploy.predictor import Predictor
from slungload.deploy.sidecar import FORMAT_VERSIONS, WINDOW, OnnxModelError, sidecar_path
from slungload.state import QUAT, STATE_DIM

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def paper_predictor(untrained_predictor) -> Predictor:
    """The paper-size network, random weights, normalisation fitted on physics windows."""
    return untrained_predictor()


@pytest.fixture(scope="module")
def exported(paper_predictor: Predictor, tmp_path_factory: pytest.TempPathFactory):
    folder = tmp_path_factory.mktemp("onnx")
    return {n: export(paper_predictor, folder / f"n{n}.onnx", horizon=n) for n in (25, 50)}


def test_a_heading_frame_network_exports_and_is_checked_at_every_heading(
    untrained_predictor, tmp_path, physics_flight
):
    """The export's own samples face every way for a heading-frame network (its statistics are
    those of heading zero), and the graph equals eager on windows turned 2 rad."""
    from slungload.config import ModelConfig
    from slungload.deploy.onnx import sample_inputs
    from slungload.state import heading_twist, quat_xyzw_to_wxyz, rotate_about_z

    predictor = untrained_predictor(ModelConfig(heading_frame=True))
    history, _ = sample_inputs(predictor, batch=16)
    twist = heading_twist(quat_xyzw_to_wxyz(torch.from_numpy(history[:, -1, QUAT]).double()))
    heading = 2 * torch.atan2(twist[:, 3], twist[:, 0])
    assert heading.abs().max() > 2.0 and heading.std() > 1.0
    result = export(predictor, tmp_path / "heading.onnx", horizon=25)
    windows = make_windows([physics_flight("t", 100, 90)], WindowConfig(history=50, horizon=25))
    states, aux = rotate_about_z(windows.states, windows.aux, 2.0)
    history, future = predict_args(dataclasses.replace(windows, states=states, aux=aux))
    got = OnnxPredictor(result.model).predict(history, future)
    np.testing.assert_allclose(got, predictor.predict(history, future), atol=1e-4, rtol=0)


@pytest.mark.parametrize("horizon", [25, 50])
def test_exported_matches_eager_on_physics_windows(
    paper_predictor, exported, horizon: int, physics_flight
):
    flights = [physics_flight(f"t{i}", 100 + i, 50 + horizon + 20) for i in range(2)]
    windows = make_windows(flights, WindowConfig(history=50, horizon=horizon, stride=7))
    history, future = predict_args(windows)  # (W, 50, 17), (W, N, 4)
    onnx = OnnxPredictor(exported[horizon].model)
    got, want = onnx.predict(history, future), paper_predictor.predict(history, future)
    assert got.shape == (len(windows), horizon, STATE_DIM) and got.dtype == np.float64
    np.testing.assert_allclose(got, want, atol=1e-4, rtol=0)
    np.testing.assert_allclose(np.linalg.norm(got[..., QUAT], axis=-1), 1.0, atol=1e-5)
    # Unbatched call and a batch of one give the same rows.
    np.testing.assert_allclose(onnx.predict(history[1], future[1]), got[1], atol=1e-6)
    # The graph follows its inputs (it is not frozen to the tracing inputs): changed future
    # inputs move both predictions alike, by far more than they disagree.
    bumped = future.copy()
    bumped[:, : horizon // 2] += [3.0, 1.0, -1.0, 0.5]
    moved = onnx.predict(history, bumped)
    np.testing.assert_allclose(moved, paper_predictor.predict(history, bumped), atol=1e-4, rtol=0)
    assert np.abs(moved - got).max() > 20 * np.abs(got - want).max()


def test_history_length_is_dynamic_on_request(paper_predictor, exported, physics_flight):
    flights = [physics_flight("h", 7, 120)]
    windows = make_windows(flights, WindowConfig(history=30, horizon=25, stride=20))
    history, future = predict_args(windows)  # M = 30, not 50
    # By default another M than the trained one is refused, naming both.
    for predictor in (OnnxPredictor(exported[25].model), paper_predictor):
        with pytest.raises(ValueError, match=r"history has 30 rows.*trained on M = 50"):
            predictor.predict(history, future)
    onnx = OnnxPredictor(exported[25].model, any_history=True)
    eager = dataclasses.replace(paper_predictor, any_history=True)
    got = onnx.predict(history, future)
    np.testing.assert_allclose(got, eager.predict(history, future), atol=1e-4, rtol=0)


def test_sidecar_describes_model_layout_and_versions(exported):
    result = exported[50]
    meta = json.loads(sidecar_path(result.model).read_text())
    assert result.sidecar == sidecar_path(result.model) and result.horizon == 50
    assert meta["format_version"] == FORMAT_VERSIONS[WINDOW] and meta["horizon"] == 50
    assert meta["inputs"][0]["shape"] == ["batch", "history", 17]
    assert meta["outputs"][0]["shape"] == ["batch", 50, 13]
    cols = meta["layout"]["state_columns"]
    assert cols[QUAT] == ["qx", "qy", "qz", "qw"]  # the file convention, x-y-z-w
    assert meta["layout"]["state_units"][:3] == ["m", "m", "m"]
    assert meta["layout"]["input_units"] == ["N", "rad/s", "rad/s", "rad/s"]
    assert meta["configs"]["model"]["hidden_size"] == 20
    assert meta["package_version"] and meta["export"]["max_abs_diff_vs_torch"] <= 1e-4


def test_wrong_horizon_and_bad_inputs_are_refused(exported):
    onnx = OnnxPredictor(exported[25].model)
    history = np.zeros((50, 17))
    history[:, 9] = 1.0
    with pytest.raises(ValueError, match=r"exported for N = 25 .* got 30"):
        onnx.predict(history, np.zeros((30, 4)))
    with pytest.raises(ValueError, match=r"OnnxPredictor.predict: expected history"):
        onnx.predict(history[:, :13], np.zeros((25, 4)))
    history[3, 2] = np.inf
    with pytest.raises(ValueError, match="history holds NaN"):
        onnx.predict(history, np.zeros((25, 4)))


def copy_export(result, folder: Path) -> tuple[Path, Path]:
    model, sidecar = folder / "m.onnx", folder / "m.json"
    model.write_bytes(result.model.read_bytes())
    sidecar.write_text(result.sidecar.read_text())
    return model, sidecar


def edit_sidecar(sidecar: Path, change) -> None:
    meta = json.loads(sidecar.read_text())
    change(meta)
    sidecar.write_text(json.dumps(meta))


@pytest.mark.parametrize(
    ("tamper", "message"),
    [
        (lambda m, s: s.unlink(), "sidecar m.json is missing"),
        (lambda m, s: s.write_text("{not json"), "not valid JSON"),
        (lambda m, s: edit_sidecar(s, lambda d: d.update(format_version=99)), "version 99"),
        (lambda m, s: m.write_bytes(m.read_bytes() + b"\0"), "checksum differs"),
        (
            lambda m, s: edit_sidecar(s, lambda d: d["layout"]["state_columns"].reverse()),
            "state_columns",
        ),
        (lambda m, s: edit_sidecar(s, lambda d: d.update(horizon=30)), "must both be"),
    ],
    ids=["missing", "json", "version", "checksum", "layout", "shape"],
)
def test_model_and_sidecar_mismatch_is_refused_naming_the_file(exported, tmp_path, tamper, message):
    model, sidecar = copy_export(exported[25], tmp_path)
    OnnxPredictor(model)  # the untouched copy loads
    tamper(model, sidecar)
    with pytest.raises(OnnxModelError, match=message) as info:
        OnnxPredictor(model)
    assert "m.onnx" in str(info.value) or "m.json" in str(info.value)


def test_runtime_path_needs_no_torch(exported):
    """The whole-window predictor on ONNX Runtime runs with torch, Lightning and MuJoCo
    blocked from importing (the onboard install)."""
    code = BLOCK + (
        "import numpy as np\n"
        "from slungload.deploy.onboard import OnnxPredictor\n"
        f"p = OnnxPredictor({str(exported[25].model)!r})\n"
        "h = np.zeros((50, 17)); h[:, 9] = 1.0; h[:, 13] = 14.0\n"
        "assert p.predict(h, np.zeros((25, 4))).shape == (25, 13)\n"
        "assert 'torch' not in sys.modules\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_export_from_a_trained_run(tmp_path: Path, tiny_run):
    """A quick checkpoint exports with its own horizon and records every config."""
    result = export(tiny_run.out, tmp_path / "tiny.onnx")
    assert result.horizon == 4 and result.history == 6
    meta = json.loads(result.sidecar.read_text())
    assert set(meta["configs"]) == {"model", "window", "params", "weights", "train"}
    assert meta["variant"] == "proposed" and meta["source"].endswith("best.ckpt")
    history, future = predict_args(tiny_run.dataset.splits["val"])
    eager = Predictor.from_checkpoint(tiny_run.out)
    got = OnnxPredictor(result.model).predict(history, future)
    np.testing.assert_allclose(got, eager.predict(history, future), atol=1e-4, rtol=0)
    with pytest.raises(ValueError, match="only 'onnx'"):
        export(tiny_run.out, tmp_path / "x.tflite", format="tflite")


def test_export_refuses_an_architecture_it_does_not_support(tmp_path, tiny_run, monkeypatch):
    """An architecture outside ``ONNX_ARCHITECTURES`` is refused by name, nothing written."""
    monkeypatch.setattr(onnx_module, "ONNX_ARCHITECTURES", ("physics-step",))
    with pytest.raises(ValueError, match="the ONNX exporter does not support the 'lstm-attention'"):
        export(tiny_run.out, tmp_path / "tiny.onnx")
    assert not any(tmp_path.iterdir())


def _spoil(change):
    """A valid paper-size (50, 17) history (x-y-z-w identity attitude, hover thrust) with
    ``change(history)`` applied."""

    def make() -> np.ndarray:
        history = np.zeros((50, 17))
        history[:, 9] = 1.0
        history[:, 13] = 14.2
        change(history)
        return history

    return make


def _set(index, value):
    def change(history: np.ndarray) -> None:
        history[index] = value

    return change


def _wxyz(history: np.ndarray) -> None:
    history[:, 6:10] = [1.0, 0.0, 0.0, 0.0]  # hover, written w-x-y-z


@pytest.mark.parametrize(
    ("spoiled", "message"),
    [
        (lambda: np.zeros((40, 17)), r"history has 40 rows, but the model was trained on M = 50"),
        (_spoil(_set((7, slice(6, 10)), 0.0)), r"row 7 has a quaternion of norm 0 .*x-y-z-w"),
        (_spoil(_wxyz), r"looks like w-x-y-z quaternions .* order is x-y-z-w"),
        (_spoil(_set((3, 11), np.nan)), r"history holds NaN .*row 3, column 11 \(pLy\) is nan"),
        (_spoil(_set((0, 15), np.inf)), r"row 0, column 15 \(wy\) is inf"),
        (_spoil(_set((4, 8), np.nan)), r"row 4, column 8 \(qz\)"),
    ],
    ids=["short-history", "zero-quaternion", "wxyz", "nan-load", "inf-rate", "nan-quaternion"],
)
def test_every_predictor_refuses_bad_inputs_alike(paper_predictor, exported, spoiled, message):
    from slungload.deploy.compiled import CompiledPredictor

    history, future = spoiled(), np.zeros((25, 4))
    predictors = {
        "Predictor": paper_predictor,
        "CompiledPredictor": CompiledPredictor(paper_predictor, warm_up=False),
        "OnnxPredictor": OnnxPredictor(exported[25].model),
    }
    messages = []
    for caller, predictor in predictors.items():
        with pytest.raises(ValueError, match=message) as info:
            predictor.predict(history, future)
        assert str(info.value).startswith(f"{caller}.predict: ")
        messages.append(str(info.value).split(": ", 1)[1])
    assert len(set(messages)) == 1, messages  # one check, one wording


def test_batched_bad_values_name_the_window(paper_predictor):
    history = np.zeros((3, 50, 17))
    history[..., 9] = 1.0
    history[2, 10, 13] = np.nan
    with pytest.raises(ValueError, match=r"window 2, row 10, column 13 \(T\) is nan"):
        paper_predictor.predict(history, np.zeros((3, 25, 4)))
    future = np.zeros((3, 25, 4))
    future[1, 24, 0] = -np.inf
    history[2, 10, 13] = 0.0
    with pytest.raises(ValueError, match=r"future_inputs holds .*window 1, row 24, column 0 \(T\)"):
        paper_predictor.predict(history, future)
    # A flight that really hovers with w near 1 in the last column passes.
    assert paper_predictor.predict(history, np.zeros((3, 25, 4))).shape == (3, 25, 13)


def test_export_out_is_a_file_in_an_existing_folder_or_a_folder(tiny_run, tmp_path: Path):
    missing = tmp_path / "no" / "such" / "m.onnx"
    with pytest.raises(FileNotFoundError, match=r"folder .*no/such does not exist"):
        export(tiny_run.out, missing)
    assert not (tmp_path / "no").exists()  # nothing created
    (tmp_path / "afile").write_text("")
    with pytest.raises(NotADirectoryError, match="afile is not a folder"):
        export(tiny_run.out, tmp_path / "afile" / "m.onnx")
    with pytest.raises(ValueError, match="overwritten by the model's JSON sidecar"):
        export(tiny_run.out, tmp_path / "m.json")
    # An existing folder receives <run name>-n<N>.onnx and its sidecar.
    folder = tmp_path / "models"
    folder.mkdir()
    result = export(tiny_run.out, folder)
    assert result.model == folder / f"{tiny_run.out.name}-n4.onnx"
    assert result.sidecar == folder / f"{tiny_run.out.name}-n4.json"
    assert json.loads(result.sidecar.read_text())["model_file"] == result.model.name
    assert export(tiny_run.out / "best.ckpt", folder, horizon=6).model.name == (
        f"{tiny_run.out.name}-n6.onnx"
    )
    assert sorted(p.name for p in folder.iterdir()) == sorted(
        f"{tiny_run.out.name}-n{n}.{ext}" for n in (4, 6) for ext in ("onnx", "json")
    )
