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

The physics step: the network's decoder calls ``compiled._physics_step`` (the compiled copy of
``physics.step`` that ``tests/test_compiled.py`` holds to it) per candidate, float64 inside. The
physics model's rollout over thousands of candidates uses ``physics_step_cols``, the same
formulas laid out over candidates in columns (float64), with sin x / x and cos x of the half
rotation angle as polynomials in x^2 (the C library's beyond 1 rad), so that its loop has no
call; ``tests/test_batched.py`` holds it to ``physics.step`` to 1e-12, so a change to the model
in ``physics.py`` fails there as well as in ``test_compiled.py``.
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
# Inlined into the caller in Numba's IR (the pieces of one loop body).
_inline = numba.njit(
    cache=True, fastmath={"contract"}, nogil=True, error_model="numpy", inline="always"
)

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


# --- the discrete model over K candidates in columns ------------------------------------------

# sin(x) / x and cos(x) as polynomials in x^2 (Taylor, to x^22 / 23!): below 1e-17 relative for
# |x| <= 1 rad (a half rotation angle h |omega| / 2 up to 1 rad, i.e. |omega| <= 66 rad/s at
# h = 0.03 s); larger angles take the C library's sin and cos (``_rotation_cols``).
_SINC = tuple((-1.0) ** n / math.factorial(2 * n + 1) for n in range(12))
_COS = tuple((-1.0) ** n / math.factorial(2 * n) for n in range(12))


@_jit
def _poly(coeffs, x2):
    p = coeffs[11]
    for n in range(10, -1, -1):
        p = p * x2 + coeffs[n]
    return p


@_inline
def _rotation_cols(u, h, dq):
    """dq (4, K) = exp(h omega / 2) (w-x-y-z) of the body rates u[1:4] (4, K): roma's
    ``rotvec_to_unitquat`` as ``compiled._rotation_step`` takes it (cos of the half angle,
    sinc / 2 times the rotation vector), vectorised over the candidates."""
    k = u.shape[1]
    for r in range(k):
        r0, r1, r2 = h * u[1, r], h * u[2, r], h * u[3, r]
        x2 = 0.25 * (r0 * r0 + r1 * r1 + r2 * r2)  # (half angle)^2
        s = 0.5 * _poly(_SINC, x2)
        dq[0, r] = _poly(_COS, x2)
        dq[1, r], dq[2, r], dq[3, r] = s * r0, s * r1, s * r2
    for r in range(k):  # rare: half angles beyond 1 rad
        r0, r1, r2 = h * u[1, r], h * u[2, r], h * u[3, r]
        half = 0.5 * math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
        if half > 1.0:
            s = 0.5 * math.sin(half) / half
            dq[0, r] = math.cos(half)
            dq[1, r], dq[2, r], dq[3, r] = s * r0, s * r1, s * r2


@_jit
def physics_step_cols(x, u, aux, c, dq, x_next, aux_next):
    """``physics.step`` for K candidates in columns, float64: x (13, K), u (4, K), aux (6, K)
    -> x_next (13, K), aux_next (6, K); dq (4, K) scratch; c ``VehicleConstants``. The same
    formulas as ``compiled._physics_step`` (held equal to ``physics.step`` by
    ``tests/test_compiled.py``; this one by ``tests/test_batched.py``), laid out so that every
    loop runs over the candidates and vectorises."""
    h, g, mq, ml, length = c.dt, c.gravity, c.mass_quad, c.mass_load, c.cable_length
    _rotation_cols(u, h, dq)
    m_sum = mq + ml
    for r in range(x.shape[1]):
        qw, qx, qy, qz = x[6, r], x[7, r], x[8, r], x[9, r]
        inv = 1.0 / max(math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz), 1e-12)
        nw, nx, ny, nz = qw * inv, qx * inv, qy * inv, qz * inv
        thrust = c.thrust_gain * u[0, r]
        tw0 = 2.0 * (nx * nz + ny * nw) * thrust
        tw1 = 2.0 * (ny * nz - nx * nw) * thrust
        tw2 = (-nx * nx - ny * ny + nz * nz + nw * nw) * thrust
        xi0 = (x[10, r] - x[0, r]) / length
        xi1 = (x[11, r] - x[1, r]) / length
        xi2 = (x[12, r] - x[2, r]) / length
        rate_sq = aux[3, r] * aux[3, r] + aux[4, r] * aux[4, r] + aux[5, r] * aux[5, r]
        along = xi0 * tw0 + xi1 * tw1 + xi2 * tw2
        t_load = -(ml / m_sum) * along + (ml * mq / m_sum) * length * rate_sq
        _axis(x, aux, x_next, aux_next, r, 0, tw0, xi0, xi1 * tw2 - xi2 * tw1, 0.0, t_load, c)
        _axis(x, aux, x_next, aux_next, r, 1, tw1, xi1, xi2 * tw0 - xi0 * tw2, 0.0, t_load, c)
        _axis(x, aux, x_next, aux_next, r, 2, tw2, xi2, xi0 * tw1 - xi1 * tw0, g, t_load, c)
        dw, dx, dy, dz = dq[0, r], dq[1, r], dq[2, r], dq[3, r]
        w = qw * dw - (qx * dx + qy * dy + qz * dz)  # Hamilton product of the unnormalised q
        a = qw * dx + dw * qx + (qy * dz - qz * dy)
        b = qw * dy + dw * qy + (qz * dx - qx * dz)
        d = qw * dz + dw * qz + (qx * dy - qy * dx)
        inv = 1.0 / max(math.sqrt(w * w + a * a + b * b + d * d), 1e-12)
        x_next[6, r], x_next[7, r], x_next[8, r], x_next[9, r] = w * inv, a * inv, b * inv, d * inv


@_inline
def _axis(x, aux, x_next, aux_next, r, i, tw, xi, cross, down, t_load, c):
    """One axis of the translational and load-rate updates of ``physics_step_cols``."""
    h, mq, ml = c.dt, c.mass_quad, c.mass_load
    acc = tw / mq - down + (t_load / mq) * xi
    acc_load = -(t_load / ml) * xi - down
    x_next[i, r] = x[i, r] + h * x[3 + i, r] + 0.5 * h * h * acc
    x_next[3 + i, r] = x[3 + i, r] + h * acc
    x_next[10 + i, r] = x[10 + i, r] + h * aux[i, r] + 0.5 * h * h * acc_load
    aux_next[i, r] = aux[i, r] + h * acc_load
    aux_next[3 + i, r] = (1.0 - c.load_damping) * aux[3 + i, r] + h * (
        -cross / (mq * c.cable_length)
    )


@_jit
def physics_rollout(x0, aux0, plans, vehicle, out):
    """``physics.rollout`` of K candidates from one state, float64: x0 (13,), aux0 (6,) =
    (vL, Omega_L), plans (K, N, 4) -> out (K, N, 13), each step ``physics_step_cols``."""
    k, n = plans.shape[0], plans.shape[1]
    x = np.empty((13, k))
    aux = np.empty((6, k))
    for j in range(13):
        x[j] = x0[j]
    for j in range(6):
        aux[j] = aux0[j]
    x_next, aux_next = np.empty((13, k)), np.empty((6, k))
    u, dq = np.empty((4, k)), np.empty((4, k))
    for step in range(n):
        for r in range(k):
            for j in range(4):
                u[j, r] = plans[r, step, j]
        physics_step_cols(x, u, aux, vehicle, dq, x_next, aux_next)
        x[:] = x_next
        aux[:] = aux_next
        for j in range(13):
            row = x[j]
            for r in range(k):
                out[r, step, j] = row[r]
