"""The numpy facade: parity with the eager network, file quaternion convention, shapes."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from flights import SMALL, WXYZ_TO_XYZW, file_rows, predict_args

from slungload.deploy.predictor import Predictor
from slungload.models.checkpoints import load_checkpoint
from slungload.state import QUAT, STATE_DIM, with_unit_quaternion

torch.set_num_threads(1)

M, N = SMALL.history, SMALL.horizon


def test_predict_matches_the_eager_model(tiny_run) -> None:
    val = tiny_run.dataset.splits["val"]
    predictor = Predictor.from_checkpoint(tiny_run.out)
    model = load_checkpoint(tiny_run.out / "best.ckpt").model
    for i in (0, len(val) - 1):
        states, inputs = val.states[i], val.inputs[i]
        got = predictor.predict(file_rows(states[:M], inputs[:M]), inputs[M:].numpy())
        with torch.no_grad():
            pred = model(states[None, :M], inputs[None, :M], inputs[None, M:]).states[0]
        want = with_unit_quaternion(pred).double().numpy()
        want[:, QUAT] = want[:, QUAT][:, WXYZ_TO_XYZW]
        assert got.shape == (N, STATE_DIM) and got.dtype == np.float64
        np.testing.assert_allclose(got, want, atol=1e-5)
        np.testing.assert_allclose(np.linalg.norm(got[:, QUAT], axis=-1), 1.0, atol=1e-6)


def test_batch_and_single_inputs_agree(tiny_run) -> None:
    val = tiny_run.dataset.splits["val"]
    predictor = Predictor.from_checkpoint(tiny_run.out / "best.ckpt")
    history, future = predict_args(val[:5])  # (5, M, 17), (5, N, 4)
    batch = predictor.predict(history, future)
    assert batch.shape == (5, N, STATE_DIM)
    for b in range(5):
        np.testing.assert_allclose(batch[b], predictor.predict(history[b], future[b]), atol=1e-5)


def test_other_horizons_and_quaternion_sign_flips(tiny_run) -> None:
    val = tiny_run.dataset.splits["val"]
    predictor = Predictor.from_checkpoint(tiny_run.out)
    history = file_rows(val.states[0, :M], val.inputs[0, :M])
    longer = np.repeat(val.inputs[0, M:].numpy(), 2, axis=0)  # 2N steps of inputs
    out = predictor.predict(history, longer)
    assert out.shape == (2 * N, STATE_DIM)
    # q and -q are one rotation: a sign jump inside the history must not change the answer.
    flipped = history.copy()
    flipped[M // 2 :, QUAT] *= -1
    np.testing.assert_allclose(predictor.predict(flipped, longer), out, atol=1e-6)


@pytest.mark.parametrize(
    ("history_shape", "future_shape"),
    [
        ((M, 13), (N, 4)),  # states without inputs
        ((M, 17), (N, 3)),  # missing a rate
        ((M, 17), (2, N, 4)),  # single history with batched inputs
        ((2, M, 17), (3, N, 4)),  # batch sizes differ
        ((17,), (4,)),  # one row is not a history
        ((0, 17), (N, 4)),  # empty history
        ((M, 17), (0, 4)),  # no future
    ],
)
def test_bad_shapes_name_expected_and_actual(
    tiny_run, history_shape: tuple, future_shape: tuple
) -> None:
    predictor = Predictor.from_checkpoint(tiny_run.out)
    with pytest.raises(ValueError, match=r"expected history .*got history") as info:
        predictor.predict(np.zeros(history_shape), np.zeros(future_shape))
    assert str(history_shape) in str(info.value) and str(future_shape) in str(info.value)


def test_non_finite_values_and_bad_checkpoints_are_refused(tiny_run, tmp_path) -> None:
    predictor = Predictor.from_checkpoint(tiny_run.out)
    history = np.zeros((M, 17))
    history[:, 9] = 1.0  # identity quaternion, x-y-z-w
    history[2, 0] = np.nan
    with pytest.raises(ValueError, match="history holds NaN"):
        predictor.predict(history, np.zeros((N, 4)))
    bad = tmp_path / "bad.ckpt"
    bad.write_text("hello")
    with pytest.raises(ValueError, match="bad.ckpt"):
        Predictor.from_checkpoint(bad)
