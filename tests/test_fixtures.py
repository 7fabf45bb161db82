"""Files written by an earlier version load and predict as they did: a checkpoint of each
architecture and an ONNX export, frozen in ``tests/fixtures/`` (``make_fixtures.py``) with the
predictions they made then."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from slungload.deploy.predictor import Predictor
from slungload.models.checkpoints import load_checkpoint

FIXTURES = Path(__file__).parent / "fixtures"


@pytest.fixture(scope="module")
def frozen() -> dict[str, np.ndarray]:
    with np.load(FIXTURES / "predictions.npz") as data:
        return dict(data)


@pytest.mark.parametrize(
    ("tag", "architecture"), [("lstm", "lstm-attention"), ("step", "physics-step")]
)
def test_an_old_checkpoint_loads_and_predicts_as_before(frozen, tag, architecture):
    loaded = load_checkpoint(FIXTURES / f"{tag}.ckpt")
    assert loaded.model_config.architecture == architecture
    predictor = Predictor.from_checkpoint(FIXTURES / f"{tag}.ckpt")
    got = predictor.predict(frozen[f"{tag}_history"], frozen[f"{tag}_future"])
    np.testing.assert_allclose(got, frozen[f"{tag}_eager"], rtol=0, atol=1e-6)
    assert np.abs(got - frozen[f"{tag}_history"][:, -1:, :13]).max() > 1e-3  # it predicts


def test_an_old_onnx_export_loads_and_predicts_as_before(frozen):
    from slungload.deploy.onboard import OnnxPredictor

    predictor = OnnxPredictor(FIXTURES / "lstm.onnx")
    got = predictor.predict(frozen["lstm_history"], frozen["lstm_future"])
    np.testing.assert_allclose(got, frozen["lstm_onnx"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(got, frozen["lstm_eager"], rtol=0, atol=1e-4)
