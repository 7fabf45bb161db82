"""The compiled math kernels (``deploy/compiled/kernels.py``), which the batch-1 predictor and
the batched backend share, against exact references: exp, tanh, the sigmoid, GELU, the LSTM
cell for one state and for candidates in columns, the attention weights."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from slungload.deploy.compiled import kernels


def test_exp_tanh_sigmoid_match_float64_references():
    x = np.linspace(-80.0, 80.0, 100_001).astype(np.float32)
    ref = x.astype(np.float64)
    exp = np.array([kernels.fexp(v) for v in x])
    assert (np.abs(exp - np.exp(ref)) / np.exp(ref)).max() < 2e-7
    tanh = np.array([kernels.ftanh(v) for v in x[::7]])
    assert np.abs(tanh - np.tanh(ref[::7])).max() < 2e-7
    small = np.linspace(-9.0, 9.0, 1001).astype(np.float32)
    sig = np.array([kernels.fsigmoid(v) for v in small])
    assert np.abs(sig - 1.0 / (1.0 + np.exp(-small.astype(np.float64)))).max() < 2e-7


def test_gelu_matches_torch_exact_gelu():
    x = np.linspace(-12.0, 12.0, 24_000).astype(np.float32).reshape(3, -1)
    got = x.copy()
    kernels.gelu(got)
    assert np.abs(got - F.gelu(torch.from_numpy(x).double()).numpy()).max() < 1e-6
    assert got[0, 0] == pytest.approx(0.0, abs=1e-9) and got[-1, -1] == pytest.approx(12.0)
    x = (np.random.default_rng(0).standard_normal((37, 53)) * 4).astype(np.float32)
    got = x.copy()
    kernels.gelu(got)
    assert np.abs(got - F.gelu(torch.from_numpy(x).double()).numpy()).max() < 1e-6


def test_lstm_cell_and_columns_match_torch_cell():
    gen = torch.Generator().manual_seed(0)
    hidden, k = 20, 9
    cell = torch.nn.LSTMCell(3, hidden)
    with torch.no_grad():
        cell.weight_ih.mul_(8.0)  # saturating gates too
    x, h, c = (torch.randn(k, n, generator=gen) for n in (3, hidden, hidden))
    with torch.no_grad():
        h_want, c_want = cell(x, (h, c))
        gates = x @ cell.weight_ih.T + h @ cell.weight_hh.T + cell.bias_ih + cell.bias_hh
    g, hc, cc = (np.ascontiguousarray(t.T.numpy()) for t in (gates, h, c))
    kernels.lstm_cols(g, cc, hc)
    np.testing.assert_allclose(hc.T, h_want.numpy(), atol=1e-6)
    np.testing.assert_allclose(cc.T, c_want.numpy(), atol=1e-6)
    for r in range(k):  # one state: the same formula, the same bits
        c1, h1 = c[r].numpy().copy(), np.zeros(hidden, np.float32)
        kernels.lstm_cell(np.ascontiguousarray(gates[r].numpy()), c1, h1)
        np.testing.assert_array_equal(c1, cc[:, r])
        np.testing.assert_array_equal(h1, hc[:, r])


def test_attention_row_is_the_softmax_of_the_scores():
    rng = np.random.default_rng(1)
    hidden, m = 16, 30
    keys = (2 * rng.standard_normal((hidden, m))).astype(np.float32)
    query = rng.standard_normal(hidden).astype(np.float32)
    att_v = rng.standard_normal(hidden).astype(np.float32)
    got = np.empty(m, np.float32)
    kernels.attention_row(query, keys, att_v, got)
    scores = att_v.astype(np.float64) @ np.tanh(keys + query[:, None].astype(np.float64))
    want = torch.softmax(torch.from_numpy(scores), 0).numpy()
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)
    assert got.sum() == pytest.approx(1.0, abs=1e-6)
