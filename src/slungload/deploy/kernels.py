"""Numba kernels for batched rollouts (``deploy.batched``): one call per operation over R rows.

The batched decoder leaves its matrix products to torch (MKL: ~70-80 GFLOP/s on one core
here, against ~25 for a hand-written Numba loop) and does everything element-wise between them
in these kernels, each one pass over the rows: GELU, the LSTM gates, the attention (scores,
softmax and the context's share of the first decoder layer's gates) and the next state (the
residual or the physics step, and the output row with its unit quaternion).

Vectorised transcendental functions. Numba calls the C library once per element for exp and
tanh (no SVML here), and a division with Python's error model is a branch that stops LLVM
from vectorising a loop. The kernels therefore compile with NumPy's error model (no
ZeroDivisionError check) and evaluate exp as 2^n p(r) (Cody-Waite reduction, r in
[-ln2/2, ln2/2], a degree-7 Taylor polynomial, relative error < 2e-7) with 2^n made from its
bit pattern (``_pow2``, an LLVM bitcast): one AVX2 loop, 0.4 ns per element on this CPU
against 1.5 ns for ``torch.exp`` and 4.5 ns for ``torch.tanh``. tanh, the sigmoid and GELU's
erf (Abramowitz and Stegun 7.1.26, absolute error < 1.5e-7) are built on it, as
``compiled.py`` does for batch 1.

The physics step is ``compiled._physics_step`` (the compiled copy of ``physics.step`` that
``tests/test_compiled.py`` holds to it), called per row: float64 inside.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from .compiled import _physics_step

# FMA contraction only (no reassociation); NumPy's error model: a division is not a branch.
_jit = numba.njit(cache=True, fastmath={"contract"}, nogil=True, error_model="numpy")

_F = np.float32
_LOG2E = _F(1.4426950408889634)
_LN2_HI = _F(0.693359375)  # few mantissa bits: n * _LN2_HI is exact
_LN2_LO = _F(0.6931471805599453 - 0.693359375)
_ROUND = _F(12582912.0)  # 1.5 * 2^23: (v + _ROUND) - _ROUND rounds v to an integer
_EXP_MIN, _EXP_MAX = _F(-87.0), _F(87.0)  # 2^n stays a normal float32
_C = tuple(_F(1.0 / math.factorial(k)) for k in range(8))
_ONE, _TWO, _HALF = _F(1.0), _F(2.0), _F(0.5)
_SQRT1_2 = _F(0.7071067811865476)
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


@_jit
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


@_jit
def ftanh(x):
    """tanh for float32 x from e^{-2|x|} (absolute error ~1e-7)."""
    e = fexp(-_TWO * abs(x))
    t = (_ONE - e) / (_ONE + e)
    return t if x >= 0 else -t


@_jit
def fsigmoid(x):
    return _ONE / (_ONE + fexp(-x))


@_jit
def gelu(x):
    """x <- x Phi(x) in place, any float32 C-contiguous array (exact GELU, erf by A&S 7.1.26),
    as max(x, 0) - |x| erfc(|x| / sqrt 2) / 2 so the loop has no branch."""
    flat = x.reshape(x.size)
    for i in range(flat.shape[0]):
        v = flat[i]
        a = abs(v)
        t = _ONE / (_ONE + _ERF_P * a)
        poly = t * (_A1 + t * (_A2 + t * (_A3 + t * (_A4 + t * _A5))))
        flat[i] = max(v, _F(0.0)) - _HALF * a * poly * fexp(-_HALF * v * v)


@_jit
def lstm_cols(gates, c, h):
    """One LSTM step for K candidates in columns: gates (4H, K) pre-activations in PyTorch's
    gate order (i, f, g, o); c, h (H, K) in place: c <- sigmoid(f) c + sigmoid(i) tanh(g),
    h <- sigmoid(o) tanh(c). Vectorised over the candidates."""
    hidden = c.shape[0]
    for j in range(hidden):
        gi, gf, gg, go = gates[j], gates[hidden + j], gates[2 * hidden + j], gates[3 * hidden + j]
        cj, hj = c[j], h[j]
        for r in range(cj.shape[0]):
            cr = fsigmoid(gf[r]) * cj[r] + fsigmoid(gi[r]) * ftanh(gg[r])
            cj[r] = cr
            hj[r] = fsigmoid(go[r]) * ftanh(cr)


@_jit
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


@_jit
def next_cols(xu, y, aux, mode, add_mean, vehicle, u_next, origin, out, step):
    """The decoder's state update for K candidates (columns), and their output rows.

    xu (17, K): (x_k relative to the origin, u_k), float32; y (13, K) the head's state rows
    (the residual gain folded in); aux (6, K) the load state (physics step). mode: 0 residual
    x + y, 1 absolute y + add_mean, 2 physics step f(x, u, aux) + y (``vehicle`` its
    constants). Then xu's state rows hold x_{k+1}, its input rows u_next (4, K) (when it has
    columns), and out[:, step] (K, N, 13) x_{k+1} + origin with a unit quaternion, float64.
    """
    k = xu.shape[1]
    if mode == 2:
        col = np.empty(17, np.float64)
        col_aux = np.empty(6, np.float64)
        x_next = np.empty(13, np.float64)
        aux_next = np.empty(6, np.float64)
        for r in range(k):
            for j in range(17):
                col[j] = xu[j, r]
            for j in range(6):
                col_aux[j] = aux[j, r]
            _physics_step(col, col_aux, vehicle, x_next, aux_next)
            for j in range(6):
                aux[j, r] = aux_next[j]
            for j in range(13):
                xu[j, r] = x_next[j]
    for j in range(13):
        row, yj = xu[j], y[j]
        for r in range(k):
            if mode == 1:
                row[r] = yj[r] + add_mean[j]
            else:
                row[r] = row[r] + yj[r]
    if u_next.shape[1] > 0:
        xu[13:] = u_next
    for r in range(k):
        qw, qx, qy, qz = float(xu[6, r]), float(xu[7, r]), float(xu[8, r]), float(xu[9, r])
        norm = max(math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz), 1e-12)
        for j in range(13):
            out[r, step, j] = xu[j, r] + origin[j]
        for j in range(4):
            out[r, step, 6 + j] = xu[6 + j, r] / norm


@_jit
def encode_rows(pre, enc_ih, enc_hh, enc_b, hs, cs, enc):
    """The stacked LSTM encoder over T rows at batch 1: pre (T, 4H) layer 0's input share plus
    its bias; enc_ih, enc_hh (L, H, 4H), enc_b (L, 4H) (layer 0's input weights unused); state
    hs, cs (L, H) updated in place; enc (T, H) the top layer's outputs."""
    layers, gates_n = enc_hh.shape[0], enc_hh.shape[2]
    g = np.empty(gates_n, np.float32)
    for t in range(pre.shape[0]):
        for layer in range(layers):
            for j in range(gates_n):
                g[j] = pre[t, j] if layer == 0 else enc_b[layer, j]
            if layer > 0:
                _accumulate(hs[layer - 1], enc_ih[layer], g)
            _accumulate(hs[layer], enc_hh[layer], g)
            _lstm_col(g, cs[layer], hs[layer])
        enc[t] = hs[layers - 1]


@_jit
def _lstm_col(g, c, h):
    """``lstm_cols`` for one state: g (4H,), c, h (H,) in place."""
    hidden = c.shape[0]
    for j in range(hidden):
        cj = fsigmoid(g[hidden + j]) * c[j] + fsigmoid(g[j]) * ftanh(g[2 * hidden + j])
        c[j] = cj
        h[j] = fsigmoid(g[3 * hidden + j]) * ftanh(cj)


@_jit
def _accumulate(x, w, out):
    """out += x @ w for one row: x (K,), w (K, N), out (N,)."""
    for k in range(w.shape[0]):
        xk, wk = x[k], w[k]
        for j in range(wk.shape[0]):
            out[j] += xk * wk[j]


@_jit
def physics_rollout(x0, aux0, plans, vehicle, out):
    """``physics.rollout`` of K candidates from one state, float64: x0 (13,), aux0 (6,) =
    (vL, Omega_L), plans (K, N, 4) -> out (K, N, 13), each step ``compiled._physics_step``."""
    xu = np.empty(17, np.float64)
    aux = np.empty(6, np.float64)
    x_next = np.empty(13, np.float64)
    aux_next = np.empty(6, np.float64)
    for r in range(plans.shape[0]):
        xu[:13] = x0
        aux[:] = aux0
        for k in range(plans.shape[1]):
            xu[13:] = plans[r, k]
            _physics_step(xu, aux, vehicle, x_next, aux_next)
            xu[:13] = x_next
            aux[:] = aux_next
            out[r, k] = x_next
