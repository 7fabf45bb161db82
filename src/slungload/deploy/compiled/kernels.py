"""The compiled (Numba) math both compiled paths share: exp and what is built on it (tanh, the
sigmoid, GELU), the LSTM cell, the attention weights, and the row products of batch 1.

Two layouts call the same element-wise formulas. Rows, for the batch-1 predictor: vectors and
(in, out) matrices, the inner loops of ``accumulate`` and ``affine`` over the outputs. Columns,
for the batched backend: K candidates as the columns of (features, K) arrays, every inner loop
over the candidates (the matrix products there are torch's BLAS).

Vectorised transcendental functions. Numba calls the C library once per element for exp and
tanh (no SVML here), and a division with Python's error model is a branch that stops LLVM from
vectorising a loop. Everything compiled here (and in the modules beside it, through ``jit``)
therefore uses NumPy's error model (no ZeroDivisionError check) and FMA contraction only (no
reassociation, so results do not depend on vector width choices). e^x is 2^n p(r): Cody-Waite
reduction, r in [-ln2/2, ln2/2], a degree-7 Taylor polynomial, relative error < 2e-7, with 2^n
made from its bit pattern (``_pow2``, an LLVM bitcast), one AVX2 loop. tanh, the sigmoid and
GELU's erf (Abramowitz and Stegun 7.1.26, absolute error < 1.5e-7) are built on it.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

# The options of every compiled function in this package.
jit = numba.njit(cache=True, fastmath={"contract"}, nogil=True, error_model="numpy")
# Inlined into the caller in Numba's IR (the pieces of one loop body).
inline = numba.njit(
    cache=True, fastmath={"contract"}, nogil=True, error_model="numpy", inline="always"
)

_F = np.float32
_LOG2E = _F(1.4426950408889634)
_LN2_HI = _F(0.693359375)  # few mantissa bits: n * _LN2_HI is exact
_LN2_LO = _F(0.6931471805599453 - 0.693359375)
_ROUND = _F(12582912.0)  # 1.5 * 2^23: (v + _ROUND) - _ROUND rounds v to an integer
_EXP_MIN, _EXP_MAX = _F(-87.0), _F(87.0)  # 2^n stays a normal float32
_C = tuple(_F(1.0 / math.factorial(k)) for k in range(8))
_ZERO, _ONE, _TWO, _HALF = _F(0.0), _F(1.0), _F(2.0), _F(0.5)
_ERF_P = _F(0.3275911 * 0.7071067811865476)  # A&S 7.1.26's p, times 1 / sqrt 2
_A1, _A2, _A3, _A4, _A5 = (_F(a) for a in (0.254829592, -0.284496736, 1.421413741,
                                           -1.453152027, 1.061405429))  # fmt: skip


@intrinsic
def _pow2(typingctx, n):
    """2^n as float32 from int32 n in [-126, 127]: the exponent bits, bit-cast (vectorises)."""
    sig = types.float32(types.int32)

    def codegen(context, builder, signature, args):
        i32 = ir.IntType(32)
        bits = builder.shl(builder.add(args[0], ir.Constant(i32, 127)), ir.Constant(i32, 23))
        return builder.bitcast(bits, ir.FloatType())

    return sig, codegen


# --- element-wise ---------------------------------------------------------------------------


@jit
def fexp(x):
    """e^x for float32 x, relative error < 2e-7 (clamped to [-87, 87])."""
    x = min(max(x, _EXP_MIN), _EXP_MAX)
    n = (x * _LOG2E + _ROUND) - _ROUND
    r = (x - n * _LN2_HI) - n * _LN2_LO
    p = _C[7]
    p = p * r + _C[6]
    p = p * r + _C[5]
    p = p * r + _C[4]
    p = p * r + _C[3]
    p = p * r + _C[2]
    p = p * r + _C[1]
    p = p * r + _C[0]
    return p * _pow2(np.int32(n))


@jit
def ftanh(x):
    """tanh for float32 x from e^{-2|x|} (absolute error ~1e-7)."""
    e = fexp(-_TWO * abs(x))
    t = (_ONE - e) / (_ONE + e)
    return t if x >= 0 else -t


@jit
def fsigmoid(x):
    return _ONE / (_ONE + fexp(-x))


@jit
def gelu(x):
    """x <- x Phi(x) in place, any float32 C-contiguous array (exact GELU, erf by A&S 7.1.26),
    as max(x, 0) - |x| erfc(|x| / sqrt 2) / 2 so the loop has no branch."""
    flat = x.reshape(x.size)
    for i in range(flat.shape[0]):
        v = flat[i]
        a = abs(v)
        t = _ONE / (_ONE + _ERF_P * a)
        poly = t * (_A1 + t * (_A2 + t * (_A3 + t * (_A4 + t * _A5))))
        flat[i] = max(v, _ZERO) - _HALF * a * poly * fexp(-_HALF * v * v)


@jit
def bias_gelu(x, b):
    """x <- GELU(x + b) in place: x (R, K) float32 C-contiguous, b (R,) a bias per row."""
    for i in range(x.shape[0]):
        row, bi = x[i], b[i]
        for r in range(row.shape[0]):
            row[r] += bi
    gelu(x)


# --- products on rows (batch 1) -------------------------------------------------------------
# Buffers are whole C-ordered arrays (slices would be typed as strided arrays, which the
# compiler does not vectorise).


@jit
def accumulate(x, w, out):
    """out += x @ w for one row: x (K,), w (K, N), out (N,)."""
    for k in range(w.shape[0]):
        xk, wk = x[k], w[k]
        for j in range(wk.shape[0]):
            out[j] += xk * wk[j]


@jit
def affine(x, w, b, out):
    """out = b + x @ w: x (R, K), w (K, N), b (N,), out (R, N). Two rows share each weight
    row load; the inner loops run over N on 1-D rows (vectorised)."""
    rows, k_dim = x.shape[0], w.shape[0]
    for r in range(rows):
        out[r] = b
    r = 0
    while r + 2 <= rows:
        o0, o1 = out[r], out[r + 1]
        for k in range(k_dim):
            x0, x1, wk = x[r, k], x[r + 1, k], w[k]
            for j in range(wk.shape[0]):
                o0[j] += x0 * wk[j]
                o1[j] += x1 * wk[j]
        r += 2
    if r < rows:
        accumulate(x[r], w, out[r])


# --- the LSTM cell --------------------------------------------------------------------------


@inline
def _cell(gi, gf, gg, go, c):
    """One LSTM unit from its pre-activations (PyTorch's gates i, f, g, o) and its cell c:
    returns (c', h') = (sigmoid(f) c + sigmoid(i) tanh(g), sigmoid(o) tanh(c'))."""
    c_new = fsigmoid(gf) * c + fsigmoid(gi) * ftanh(gg)
    return c_new, fsigmoid(go) * ftanh(c_new)


@jit
def lstm_cell(g, c, h):
    """One LSTM step of one state from its pre-activations g (4H,): c, h (H,) in place."""
    hidden = c.shape[0]
    for j in range(hidden):
        c[j], h[j] = _cell(g[j], g[hidden + j], g[2 * hidden + j], g[3 * hidden + j], c[j])


@jit
def lstm_cols(gates, c, h):
    """One LSTM step for K candidates in columns: gates (4H, K) pre-activations; c, h (H, K) in
    place. Vectorised over the candidates."""
    hidden = c.shape[0]
    for j in range(hidden):
        gi, gf, gg, go = gates[j], gates[hidden + j], gates[2 * hidden + j], gates[3 * hidden + j]
        cj, hj = c[j], h[j]
        for r in range(cj.shape[0]):
            cj[r], hj[r] = _cell(gi[r], gf[r], gg[r], go[r], cj[r])


@jit
def lstm_cols_bias(gates, bias, c, h):
    """``lstm_cols`` of the pre-activations gates (4H, K) + bias (4H,) (gates unchanged)."""
    hidden = c.shape[0]
    for j in range(hidden):
        gi, gf, gg, go = gates[j], gates[hidden + j], gates[2 * hidden + j], gates[3 * hidden + j]
        bi, bf = bias[j], bias[hidden + j]
        bg, bo = bias[2 * hidden + j], bias[3 * hidden + j]
        cj, hj = c[j], h[j]
        for r in range(cj.shape[0]):
            cj[r], hj[r] = _cell(gi[r] + bi, gf[r] + bf, gg[r] + bg, go[r] + bo, cj[r])


@jit
def lstm_cols_add(gates, add, c, h):
    """``lstm_cols`` of the pre-activations gates + add, both (4H, K) (gates unchanged)."""
    hidden = c.shape[0]
    for j in range(hidden):
        gi, gf, gg, go = gates[j], gates[hidden + j], gates[2 * hidden + j], gates[3 * hidden + j]
        ai, af, ag, ao = add[j], add[hidden + j], add[2 * hidden + j], add[3 * hidden + j]
        cj, hj = c[j], h[j]
        for r in range(cj.shape[0]):
            cj[r], hj[r] = _cell(gi[r] + ai[r], gf[r] + af[r], gg[r] + ag[r], go[r] + ao[r], cj[r])


@jit
def lstm_layer(x, w_in, w_hh, b, c, h, g):
    """One step of one layer of a stacked LSTM, one state: g (4H,) <- b + x @ w_in + h @ w_hh,
    then c, h (H,) in place. x (K,), w_in (K, 4H), w_hh (H, 4H), b (4H,)."""
    for j in range(g.shape[0]):
        g[j] = b[j]
    accumulate(x, w_in, g)
    accumulate(h, w_hh, g)
    lstm_cell(g, c, h)


@jit
def encode_rows(pre, enc_ih, enc_hh, enc_b, hs, cs, enc):
    """The stacked LSTM encoder over T rows of one state: pre (T, 4H) layer 0's input share
    plus its bias; enc_ih, enc_hh (L, H, 4H), enc_b (L, 4H) (layer 0's input weights unused);
    hs, cs (L, H) updated in place; enc (T, H) the top layer's outputs."""
    layers, gates_n = enc_hh.shape[0], enc_hh.shape[2]
    g = np.empty(gates_n, np.float32)
    for t in range(pre.shape[0]):
        for j in range(gates_n):
            g[j] = pre[t, j]
        accumulate(hs[0], enc_hh[0], g)
        lstm_cell(g, cs[0], hs[0])
        for layer in range(1, layers):
            lstm_layer(
                hs[layer - 1], enc_ih[layer], enc_hh[layer], enc_b[layer], cs[layer], hs[layer], g
            )
        enc[t] = hs[layers - 1]


# --- the attention weights ------------------------------------------------------------------


@jit
def attention_row(query, keys, att_v, weights):
    """Bahdanau attention weights of one query over M encoder rows: query (H,) = U^T h,
    keys (H, M) = W^T enc (one column per row), att_v (H,) -> weights (M,) =
    softmax_j(v . tanh(key_j + query)). The inner loops run over the M rows."""
    hidden, m = keys.shape[0], keys.shape[1]
    for j in range(m):
        weights[j] = _ZERO
    for i in range(hidden):
        vi, key, q = att_v[i], keys[i], query[i]
        for j in range(m):
            weights[j] += vi * ftanh(key[j] + q)
    top = weights[0]
    for j in range(1, m):
        top = max(top, weights[j])
    total = _ZERO
    for j in range(m):
        weights[j] = fexp(weights[j] - top)
        total += weights[j]
    total = _ONE / total
    for j in range(m):
        weights[j] *= total


@jit
def attention_cols(query, att_v, keys, keys_last, ctx_last, bias0, weights, gates):
    """Bahdanau attention of K candidates (columns) over a history whose first M-1 encoder
    outputs are shared by all of them.

    query (H, K) = U^T h of the decoder's top hidden state; att_v (H,); keys (H, M-1) the
    shared rows' keys W^T enc_j; keys_last (H, K) each candidate's last key; ctx_last (4H, K)
    each candidate's last encoder output through the first decoder layer's context weights;
    bias0 (4H,) that layer's bias. Writes the softmax weights of the shared rows into weights
    (M-1, K) and gates (4H, K) = bias0 + w_last ctx_last: the caller adds (shared rows' ctx)^T
    @ weights with one matrix product. Every inner loop runs over the K candidates.
    """
    hidden, shared, k = keys.shape[0], keys.shape[1], query.shape[1]
    last = np.zeros(k, np.float32)
    top = np.empty(k, np.float32)
    total = np.zeros(k, np.float32)
    for j in range(shared):  # score_j = v . tanh(key_j + q)
        s = weights[j]
        s[:] = 0.0
        for i in range(hidden):
            vi, key, q = att_v[i], keys[i, j], query[i]
            for r in range(k):
                s[r] += vi * ftanh(key + q[r])
    for i in range(hidden):
        vi, key, q = att_v[i], keys_last[i], query[i]
        for r in range(k):
            last[r] += vi * ftanh(key[r] + q[r])
    top[:] = last
    for j in range(shared):
        s = weights[j]
        for r in range(k):
            top[r] = max(top[r], s[r])
    for j in range(shared):
        s = weights[j]
        for r in range(k):
            s[r] = fexp(s[r] - top[r])
            total[r] += s[r]
    for r in range(k):
        last[r] = fexp(last[r] - top[r])
        total[r] = _ONE / (total[r] + last[r])
        last[r] *= total[r]
    for j in range(shared):
        s = weights[j]
        for r in range(k):
            s[r] *= total[r]
    for g in range(gates.shape[0]):
        row, ctx, b = gates[g], ctx_last[g], bias0[g]
        for r in range(k):
            row[r] = b + last[r] * ctx[r]
