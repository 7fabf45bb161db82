"""The Numba batch-1 predictor: its element-wise kernels against exact references, and its
predictions against the eager network for every model mode."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from flights import predict_args

from slungload.config import ModelConfig, WindowConfig
from slungload.data.windows import make_windows
from slungload.deploy.compiled import (
    PARITY_TOLERANCE,
    CompiledPredictor,
    _exp,
    _gelu,
    _lstm_update,
    fold,
)
from slungload.models.lstm_attention import SlungLoadNet
from slungload.state import QUAT, STATE_DIM

torch.set_num_threads(1)

M = 50


def test_exp_matches_numpy_to_float32_precision():
    x = np.linspace(-80.0, 80.0, 100_001).astype(np.float32)
    got = x.copy()
    _exp(got, np.empty(x.shape, np.int32), 0, x.size)
    want = np.exp(x.astype(np.float64))
    rel = np.abs(got - want) / want
    assert rel.max() < 5e-7
    # Only the requested range is touched.
    part = x.copy()
    _exp(part, np.empty(x.shape, np.int32), 10, 20)
    np.testing.assert_array_equal(part[:10], x[:10])
    np.testing.assert_array_equal(part[20:], x[20:])


def test_gelu_matches_torch_exact_gelu():
    x = np.linspace(-12.0, 12.0, 24_000).astype(np.float32).reshape(3, -1)
    got = x.copy()
    _gelu(got, np.empty(x.size, np.float32), np.empty(x.size, np.int32))
    want = F.gelu(torch.from_numpy(x).double()).numpy()
    assert np.abs(got - want).max() < 1e-6
    assert got[0, 0] == pytest.approx(0.0, abs=1e-9) and got[-1, -1] == pytest.approx(12.0)


def test_lstm_update_matches_torch_cell():
    torch.manual_seed(1)
    hidden = 20
    gates = (4 * torch.randn(4 * hidden)).float()
    c0 = torch.randn(hidden).float()
    # torch's cell with identity input weights and zero recurrent weights gives gates = input.
    cell = torch.nn.LSTMCell(4 * hidden, hidden).double()
    with torch.no_grad():
        cell.weight_ih.copy_(torch.eye(4 * hidden))
        cell.weight_hh.zero_()
        cell.bias_ih.zero_()
        cell.bias_hh.zero_()
        h_want, c_want = cell(
            gates.double()[None], (torch.zeros(1, hidden).double(), c0.double()[None])
        )
    c, h = c0.numpy().copy(), np.zeros(hidden, np.float32)
    _lstm_update(
        gates.numpy(), c, h, np.empty(5 * hidden, np.float32), np.empty(5 * hidden, np.int32)
    )
    np.testing.assert_allclose(c, c_want[0].numpy(), atol=1e-6)
    np.testing.assert_allclose(h, h_want[0].numpy(), atol=1e-6)


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
    flipped[20:35, 6:10] *= -1.0  # q and -q: the same attitude
    flipped[:, 6:10] *= 1.05  # not unit, within the tolerance: normalised on the way in
    np.testing.assert_allclose(compiled.predict(flipped, future), base, atol=1e-5)
    np.testing.assert_allclose(predictor.predict(flipped, future), base, atol=PARITY_TOLERANCE)
    flipped[:, 6:10] *= 1.7  # far from unit: wrong columns or a broken estimator, refused
    for fn in (compiled.predict, predictor.predict):
        with pytest.raises(ValueError, match=r"row 0 has a quaternion of norm 1\.7\d.*x-y-z-w"):
            fn(flipped, future)


def test_unbatched_call_and_checks(untrained_predictor):
    compiled = CompiledPredictor(untrained_predictor(), warm_up=False)
    history = np.zeros((M, 17))
    history[:, 9] = 1.0
    out = compiled.predict(history, np.zeros((7, 4)))
    assert out.shape == (7, STATE_DIM) and np.isfinite(out).all()
    with pytest.raises(ValueError, match=r"CompiledPredictor\.predict.*history"):
        compiled.predict(np.zeros((M, 13)), np.zeros((7, 4)))
    with pytest.raises(ValueError, match=r"CompiledPredictor\.predict"):
        compiled.predict(history, np.full((7, 4), math.nan))


def test_fold_refuses_other_layer_counts():
    with pytest.raises(ValueError, match="three embedding"):
        fold(SlungLoadNet(ModelConfig(embed_sizes=(64, 64))))
