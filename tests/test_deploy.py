"""ONNX export: parity with the eager network on physics windows, sidecar checks, runtime path."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from flights import file_rows, swinging_flight

from slungload.config import ModelConfig, VehicleParams, WindowConfig
from slungload.data.dataset import Dataset
from slungload.data.windows import make_windows
from slungload.deploy.onnx import (
    FORMAT_VERSION,
    OnnxModelError,
    OnnxPredictor,
    export,
    sidecar_path,
)
from slungload.deploy.predictor import Predictor
from slungload.models.lstm_attention import SlungLoadNet
from slungload.state import QUAT, STATE_DIM
from slungload.training.trainer import train

torch.set_num_threads(1)

PAPER = WindowConfig(history=50, horizon=25)


@pytest.fixture(scope="module")
def paper_predictor() -> Predictor:
    """The paper-size network, random weights, normalisation fitted on physics windows."""
    torch.manual_seed(0)
    flights = [swinging_flight(f"f{i}", i, 140) for i in range(3)]
    windows = make_windows(flights, WindowConfig(history=50, horizon=50))
    model = SlungLoadNet(ModelConfig())
    model.fit_normalization(windows.states, windows.inputs, origin_step=PAPER.history - 1)
    return Predictor(model.eval(), PAPER, VehicleParams(), "proposed")


@pytest.fixture(scope="module")
def exported(paper_predictor: Predictor, tmp_path_factory: pytest.TempPathFactory):
    folder = tmp_path_factory.mktemp("onnx")
    return {n: export(paper_predictor, folder / f"n{n}.onnx", horizon=n) for n in (25, 50)}


@pytest.mark.parametrize("horizon", [25, 50])
def test_exported_matches_eager_on_physics_windows(paper_predictor, exported, horizon: int):
    flights = [swinging_flight(f"t{i}", 100 + i, 50 + horizon + 20) for i in range(2)]
    windows = make_windows(flights, WindowConfig(history=50, horizon=horizon, stride=7))
    history = file_rows(windows.states[:, :50], windows.inputs[:, :50])  # (W, 50, 17)
    future = windows.inputs[:, 50:].double().numpy()  # (W, N, 4)
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


def test_history_length_is_dynamic(paper_predictor, exported):
    flights = [swinging_flight("h", 7, 120)]
    windows = make_windows(flights, WindowConfig(history=30, horizon=25, stride=20))
    history = file_rows(windows.states[:, :30], windows.inputs[:, :30])  # M = 30, not 50
    future = windows.inputs[:, 30:].double().numpy()
    got = OnnxPredictor(exported[25].model).predict(history, future)
    np.testing.assert_allclose(got, paper_predictor.predict(history, future), atol=1e-4, rtol=0)


def test_sidecar_describes_model_layout_and_versions(exported):
    result = exported[50]
    meta = json.loads(sidecar_path(result.model).read_text())
    assert result.sidecar == sidecar_path(result.model) and result.horizon == 50
    assert meta["format_version"] == FORMAT_VERSION and meta["horizon"] == 50
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


def test_runtime_path_does_not_import_lightning(exported):
    code = (
        "import sys, numpy as np\n"
        "from slungload.deploy.onnx import OnnxPredictor\n"
        f"p = OnnxPredictor({str(exported[25].model)!r})\n"
        "h = np.zeros((50, 17)); h[:, 9] = 1.0; h[:, 13] = 14.0\n"
        "assert p.predict(h, np.zeros((25, 4))).shape == (25, 13)\n"
        "heavy = ('lightning', 'slungload.training')\n"
        "bad = sorted(m for m in sys.modules if m.startswith(heavy))\n"
        "assert not bad, bad\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_export_from_a_trained_run(tmp_path: Path):
    """A quick checkpoint exports with its own horizon and records every config."""
    small = WindowConfig(history=6, horizon=4)
    splits = {
        split: make_windows([swinging_flight(split, seed, 40)], small)
        for seed, split in enumerate(("train", "val", "test"))
    }
    dataset = Dataset(
        folder=tmp_path,
        params=VehicleParams(),
        params_source="test",
        window=small,
        splits=splits,
        flights={},
    )
    tiny = ModelConfig(
        embed_sizes=(16, 16), hidden_size=8, num_layers=1, head_sizes=(16,), dropout=0
    )
    train(dataset, out=tmp_path / "run", preset="quick", model_config=tiny, progress=False)
    result = export(tmp_path / "run", tmp_path / "tiny.onnx")
    assert result.horizon == 4 and result.history == 6
    meta = json.loads(result.sidecar.read_text())
    assert set(meta["configs"]) == {"model", "window", "params", "weights", "train"}
    assert meta["variant"] == "proposed" and meta["source"].endswith("best.ckpt")
    val = dataset.splits["val"]
    history = file_rows(val.states[:, :6], val.inputs[:, :6])
    future = val.inputs[:, 6:].double().numpy()
    eager = Predictor.from_checkpoint(tmp_path / "run")
    got = OnnxPredictor(result.model).predict(history, future)
    np.testing.assert_allclose(got, eager.predict(history, future), atol=1e-4, rtol=0)
    with pytest.raises(ValueError, match="only 'onnx'"):
        export(tmp_path / "run", tmp_path / "x.tflite", format="tflite")
