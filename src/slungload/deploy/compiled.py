"""Batch-1 prediction compiled with Numba: the network's forward pass for a control loop.

    fast = CompiledPredictor(Predictor.from_checkpoint("runs/proposed"))
    states = fast.predict(history, future_inputs)        # same call and result as Predictor

Why a third path beside eager torch and the ONNX export: at batch 1 the decoder is ~60 tiny
operators per horizon step, and every runtime that dispatches operators one at a time pays
for each (~7 us in eager torch, ~1 us in ONNX Runtime) more than the arithmetic
(docs/deployment.md). Here each forward pass is one compiled call: element-wise work is fused
into the loops around the matrix-vector products, and nothing is allocated per step.

The arithmetic is the network's (``model.SlungLoadNet``), rearranged exactly:

- the input standardisation is folded into the first embedding layer, and the decoder runs in
  physical units relative to the last measured position (``fold``);
- the head's first two Linears (no activation between them) are multiplied into one;
- the residual gain ``delta_std`` is folded into the head's last layer, and the slack rows
  are dropped (they are for the loss only);
- the attention context enters the decoder's first LSTM layer only through W_ih[:, :H], so
  the encoder outputs are projected by it once (``enc_ctx``) and the context is never formed;
- exp, tanh, sigmoid and erf are evaluated by short, vectorisable formulas (``_exp``: 2^n
  times a degree-7 Taylor polynomial of 2^r, |r| <= 1/2; erf: Abramowitz and Stegun 7.1.26,
  absolute error below 1.5e-7), where the compiler would otherwise call the C library once
  per element.

The physics-step network (``models.physics_step.PhysicsStepNet``) compiles too: the same
loop, whose decoder step is x_{k+1} = f(x_k, u_k, a_k) + delta_std * out_k (the residual gain
folded into the head as above) instead of x_k + delta_std * out_k, with the load state a =
(vL, Omega_L) started by ``_estimate_load_state`` from the last two history rows and carried by
f. ``_physics_step`` and ``_estimate_load_state`` are a **compiled copy** of
``physics.step`` and ``load_state.estimate_load_state``: the model is written once, in
batched torch (``physics.py``), where the loss, training, the eager predictor and the ONNX
export use it; compiled code cannot call torch, and a batch-1 step is a few dozen scalar
operations, which a compiled loop does in well under a microsecond. The copy uses the same
formulas in the same form (roma's rotation matrix and quaternion product, the same sinc,
normalisation floors and cross products), computed in float64 and rounded once to the state's
float32; ``tests/test_compiled.py`` holds it equal to the torch functions (float64: to
round-off; float32: ~1e-6 relative), so the two cannot drift apart unnoticed. A change to the
model in ``physics.py`` must be made here too (the test then says where they differ).

Float32 throughout (except inside the physics step). Predictions agree with
``Predictor.predict`` to ~1e-6 (tested against ``PARITY_TOLERANCE``); they are not
bit-identical (different summation order).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..config import VehicleParams
from ..load_state import LOAD_FIT_STEPS, load_fit_coefficients
from ..models.lstm_attention import SlungLoadNet
from ..models.physics_step import PhysicsStepNet
from ..physics import VehicleConstants
from ..state import INPUT_DIM, STATE_DIM
from .predictor import PARITY_TOLERANCE, Predictor, check_inputs, torch_threads, unbatch

# What ``fold`` knows how to compile: architecture name -> the class a model must be.
_COMPILED_CLASSES: dict[str, type[SlungLoadNet]] = {
    cls.architecture: cls for cls in (SlungLoadNet, PhysicsStepNet)
}
COMPILED_ARCHITECTURES = tuple(_COMPILED_CLASSES)

# FMA contraction only: no reassociation, so results do not depend on vector width choices.
_FLAGS = {"contract"}
_jit = numba.njit(cache=True, fastmath=_FLAGS, nogil=True)

_LOG2E_F = np.float32(1.4426950408889634)
_LN2_HI = np.float32(0.693359375)  # few mantissa bits: n * _LN2_HI is exact
_LN2_LO = np.float32(0.6931471805599453 - 0.693359375)
_HALF = np.float32(0.5)
_EXP_MIN, _EXP_MAX = np.float32(-87.0), np.float32(87.0)  # 2^n stays a normal float32
_EXP_TAYLOR = tuple(np.float32(1.0 / math.factorial(k)) for k in range(8))
_SQRT1_2 = 0.7071067811865476
# Abramowitz & Stegun 7.1.26: erf(x) = 1 - t (a1 + t (a2 + ...)) exp(-x^2), t = 1 / (1 + p x).
_ERF_P = 0.3275911
_ERF_A = (0.254829592, -0.284496736, 1.421413741, -1.453152027, 1.061405429)


class FoldedWeights(NamedTuple):
    """The network's weights rearranged for the compiled forward pass (float32, C order).

    Matrices are (in, out). Rows of the state blocks are in the package layout (q w-x-y-z);
    E0 = first embedding width, H = LSTM width, G = 4H gates in PyTorch's order (i, f, g, o).
    """

    emb_xu: np.ndarray  # (17, E0) first embedding layer on (x - origin, u), physical units
    emb_b: np.ndarray  # (E0,) its bias with the standardisation folded in
    emb1_w: np.ndarray  # (E0, E1)
    emb1_b: np.ndarray  # (E1,)
    emb2_w: np.ndarray  # (E1, E)
    emb2_b: np.ndarray  # (E,)
    enc_emb: np.ndarray  # (E, G) encoder layer 0 input weights
    enc_ih: np.ndarray  # (L, H, G) encoder input weights of layers >= 1 (layer 0 unused)
    enc_hh: np.ndarray  # (L, H, G)
    enc_b: np.ndarray  # (L, G) b_ih + b_hh
    att_w: np.ndarray  # (H, H) keys = enc W
    att_u: np.ndarray  # (H, H) query = h U
    att_v: np.ndarray  # (H,)
    dec_ctx: np.ndarray  # (H, G) decoder layer 0, context columns
    dec_emb: np.ndarray  # (E, G) decoder layer 0, embedding columns
    dec_ih: np.ndarray  # (L, H, G) decoder input weights of layers >= 1 (layer 0 unused)
    dec_hh: np.ndarray  # (L, H, G)
    dec_b: np.ndarray  # (L, G)
    head1_w: np.ndarray  # (H, K1) the head's first two Linears multiplied
    head1_b: np.ndarray  # (K1,)
    head2_w: np.ndarray  # (K1, K2)
    head2_b: np.ndarray  # (K2,)
    head3_w: np.ndarray  # (K2, 13) state rows only, times the residual gain
    head3_b: np.ndarray  # (13,)
    add_mean: np.ndarray  # (13,) non-residual heads: added to the output (else zero)
    residual: bool  # x_{k+1} = x_k + head(...) (else x_{k+1} = head(...) + add_mean)
    origin_shift: np.ndarray  # (3, 13) vehicle position -> origin offset (model.origin)
    architecture: str  # the model's name in ``models.MODELS`` (one of COMPILED_ARCHITECTURES)
    physics_step: bool  # x_{k+1} = f(x_k, u_k, a_k) + head(...) (``PhysicsStepNet``)
    vehicle: VehicleConstants  # f's constants as floats (the model's; defaults where f is unused)
    # The smoothed load estimate's weights (``load_state.load_fit_coefficients``): row K - 3
    # holds the K weights for a window of K = min(M, LOAD_FIT_STEPS) steps; (0, 0) for the
    # backward difference.
    load_filters: np.ndarray


def unsupported(model: nn.Module) -> str | None:
    """Why ``fold`` cannot compile ``model`` (its architecture or its layer structure), or
    None when it can."""
    name = getattr(model, "architecture", type(model).__name__)
    cls = _COMPILED_CLASSES.get(name)
    if cls is None or not isinstance(model, cls):
        return (
            f"the compiled predictor does not support the {name!r} architecture (it supports "
            f"{list(COMPILED_ARCHITECTURES)})"
        )
    cfg = model.config
    if len(cfg.embed_sizes) != 3 or len(cfg.head_sizes) != 3:
        return (
            "CompiledPredictor supports three embedding and three head layers (the paper's "
            f"shape); got embed_sizes={cfg.embed_sizes}, head_sizes={cfg.head_sizes}"
        )
    return None


def fold(model: SlungLoadNet) -> FoldedWeights:
    """Rearrange ``model``'s weights for the compiled pass (see the module doc); a model it
    cannot compile is a ``ValueError`` naming why (``unsupported``)."""
    reason = unsupported(model)
    if reason is not None:
        raise ValueError(reason)
    cfg = model.config
    with torch.no_grad():
        d = {k: v.detach().double().cpu() for k, v in model.state_dict().items()}
    h, layers = cfg.hidden_size, cfg.num_layers
    # Without normalisation the buffers keep their identity values (zero mean, unit std).
    ms, ss, mu, su = d["state_mean"], d["state_std"], d["input_mean"], d["input_std"]

    # First layer on z = (x - o - ms) / ss and v = (u - mu) / su, rewritten on x - o and u.
    w0, b0 = d["embed.layers.0.weight"], d["embed.layers.0.bias"]  # (E0, 17), (E0,)
    emb_x = (w0[:, :STATE_DIM] / ss).t()
    emb_u = (w0[:, STATE_DIM:] / su).t()
    emb_b = b0 - ms @ emb_x - mu @ emb_u

    def lstm(prefix: str, i: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return (
            d[f"{prefix}.weight_ih_l{i}"].t(),
            d[f"{prefix}.weight_hh_l{i}"].t(),
            d[f"{prefix}.bias_ih_l{i}"] + d[f"{prefix}.bias_hh_l{i}"],
        )

    enc_ih = torch.zeros(layers, h, 4 * h, dtype=torch.float64)
    dec_ih = torch.zeros(layers, h, 4 * h, dtype=torch.float64)
    enc_hh, enc_b, dec_hh, dec_b = [], [], [], []
    for i in range(layers):
        ih, hh, b = lstm("encoder", i)
        if i == 0:
            enc_emb = ih
        else:
            enc_ih[i] = ih
        enc_hh.append(hh)
        enc_b.append(b)
        ih, hh, b = lstm("decoder", i)
        if i == 0:
            dec_ctx, dec_emb = ih[:h], ih[h:]
        else:
            dec_ih[i] = ih
        dec_hh.append(hh)
        dec_b.append(b)

    # Head: Linear -> Linear (no activation between) -> GELU -> Linear -> GELU -> Linear.
    hw = [d[f"head.layers.{i}.weight"] for i in range(4)]
    hb = [d[f"head.layers.{i}.bias"] for i in range(4)]
    head1_w = (hw[1] @ hw[0]).t()
    head1_b = hw[1] @ hb[0] + hb[1]
    w3, b3 = hw[3][:STATE_DIM].t(), hb[3][:STATE_DIM]
    add_mean = torch.zeros(STATE_DIM, dtype=torch.float64)
    # The decoder's state is physical (relative); the head's output unit depends on the mode.
    if cfg.residual:
        gain = d["delta_std"] if cfg.normalize else torch.ones_like(ms)
    else:
        gain, add_mean = ss, ms
    w3, b3 = w3 * gain, b3 * gain

    f32 = lambda t: np.ascontiguousarray(t.numpy(), dtype=np.float32)  # noqa: E731
    return FoldedWeights(
        emb_xu=f32(torch.cat([emb_x, emb_u])),
        emb_b=f32(emb_b),
        emb1_w=f32(d["embed.layers.1.weight"].t()),
        emb1_b=f32(d["embed.layers.1.bias"]),
        emb2_w=f32(d["embed.layers.2.weight"].t()),
        emb2_b=f32(d["embed.layers.2.bias"]),
        enc_emb=f32(enc_emb),
        enc_ih=f32(enc_ih),
        enc_hh=f32(torch.stack(enc_hh)),
        enc_b=f32(torch.stack(enc_b)),
        att_w=f32(d["attention.W.weight"].t()),
        att_u=f32(d["attention.U.weight"].t()),
        att_v=f32(d["attention.v.weight"][0]),
        dec_ctx=f32(dec_ctx),
        dec_emb=f32(dec_emb),
        dec_ih=f32(dec_ih),
        dec_hh=f32(torch.stack(dec_hh)),
        dec_b=f32(torch.stack(dec_b)),
        head1_w=f32(head1_w),
        head1_b=f32(head1_b),
        head2_w=f32(hw[2].t()),
        head2_b=f32(hb[2]),
        head3_w=f32(w3),
        head3_b=f32(b3),
        add_mean=f32(add_mean),
        residual=bool(cfg.residual),
        origin_shift=f32(model.position_shift.double().cpu()),
        architecture=model.architecture,
        physics_step=model.architecture == PhysicsStepNet.architecture,
        vehicle=VehicleConstants.of(getattr(model, "params", None) or VehicleParams()),
        load_filters=_load_filters(cfg.load_estimate, model),
    )


def _load_filters(load_estimate: str, model: nn.Module) -> np.ndarray:
    """``FoldedWeights.load_filters`` for the model's load estimate."""
    if load_estimate != "smoothed":
        return np.zeros((0, 0), np.float64)
    dt = model.params.dt
    table = np.zeros((LOAD_FIT_STEPS - 2, LOAD_FIT_STEPS), np.float64)
    for k in range(3, LOAD_FIT_STEPS + 1):
        table[k - 3, :k] = load_fit_coefficients(k, dt)
    return table


class CompiledPredictor:
    """``Predictor.predict`` as one compiled call per window (numpy in, numpy out).

    Same arguments, checks and result as ``Predictor.predict`` (file layout, quaternion
    x-y-z-w, float64 out; M and ``threads`` as the wrapped ``Predictor``'s). Single-threaded
    by default; windows of a batch run one after another, so it is meant for batch 1 (larger
    batches are faster on the torch or ONNX paths).
    """

    def __init__(self, predictor: Predictor, *, warm_up: bool = True) -> None:
        self.predictor = predictor
        self.weights = w = fold(predictor.model)
        t = torch.from_numpy  # shares memory with the folded arrays
        self._embedding = [
            (t(w.emb_xu), t(w.emb_b)),
            (t(w.emb1_w), t(w.emb1_b)),
            (t(w.emb2_w), t(w.emb2_b)),
        ]
        self._enc_emb, self._enc_b0 = t(w.enc_emb), t(w.enc_b[0])
        if warm_up:  # compile (or load from Numba's cache) now, not in the first control step
            m = predictor.window.history
            history = np.zeros((m, STATE_DIM + INPUT_DIM), dtype=np.float32)
            history[:, 9] = 1.0  # unit quaternion (x-y-z-w)
            self.predict(history, np.zeros((2, INPUT_DIM), dtype=np.float32))

    @classmethod
    def from_checkpoint(cls, path: str, **kwargs) -> CompiledPredictor:
        """Load a run folder or ``.ckpt`` (as ``Predictor.from_checkpoint``)."""
        return cls(Predictor.from_checkpoint(path), **kwargs)

    def predict(self, history: np.ndarray, future_inputs: np.ndarray) -> np.ndarray:
        """history (M, 17) or (B, M, 17), future_inputs (N, 4) or (B, N, 4), file layout ->
        (N, 13) or (B, N, 13) float64 states, quaternion unit and x-y-z-w."""
        p = self.predictor
        hist, fut, single = check_inputs(
            history,
            future_inputs,
            caller="CompiledPredictor.predict",
            history_rows=None if p.any_history else p.history,
        )
        hist = np.ascontiguousarray(hist, dtype=np.float32)
        fut = np.ascontiguousarray(fut, dtype=np.float32)
        w = self.weights
        batch, m = hist.shape[:2]
        if w.physics_step and m < 2:  # as PhysicsStepNet.start_rollout
            raise ValueError(
                f"CompiledPredictor.predict: the {w.architecture!r} network needs M >= 2 "
                f"history rows to estimate the load state (vL, Omega_L); got M = {m}"
            )
        xu = np.empty((batch, m, STATE_DIM + INPUT_DIM), dtype=np.float32)
        origin = np.empty((batch, STATE_DIM), dtype=np.float32)
        for b in range(batch):
            _relative_rows(hist[b], w.origin_shift, xu[b], origin[b])
        with torch_threads(p.threads):  # the only torch work: one matrix product
            pre = self._encoder_inputs(xu)
        out = np.empty((batch, fut.shape[1], STATE_DIM), dtype=np.float32)
        for b in range(batch):
            _forward(xu[b], origin[b], pre[b], fut[b], w, out[b])
        return unbatch(out, single)

    def _encoder_inputs(self, xu: np.ndarray) -> np.ndarray:
        """(B, M, 17) rows -> (B, M, 4H): embedding and encoder layer 0's input part.

        Matrix-matrix work over the M history rows, done by torch's BLAS and vectorised GELU
        (several times faster here than the compiled loops); the recurrent part stays compiled.
        """
        batch, m, _ = xu.shape
        with torch.inference_mode():
            e = torch.from_numpy(xu).reshape(batch * m, -1)
            for weight, bias in self._embedding:
                e = F.gelu(torch.addmm(bias, e, weight))
            pre = torch.addmm(self._enc_b0, e, self._enc_emb)
        return pre.reshape(batch, m, -1).numpy()


# --- kernels ---------------------------------------------------------------------------------
# Buffers are whole C-ordered arrays with explicit bounds (slices would be typed as strided
# arrays, which the compiler does not vectorise).


@_jit
def _exp(x, bits, lo, hi):
    """x[lo:hi] <- exp(x[lo:hi]), relative error ~2e-7; bits: int32 scratch, len(x).

    e^x = 2^n e^r with n = round(x / ln 2), |r| <= ln2 / 2, e^r by its Taylor polynomial of
    degree 7 and 2^n written as float32 bits; x is clamped to [-87, 87]."""
    c0, c1, c2, c3, c4, c5, c6, c7 = _EXP_TAYLOR
    for i in range(lo, hi):
        xi = min(max(x[i], _EXP_MIN), _EXP_MAX)
        n = np.floor(xi * _LOG2E_F + _HALF)
        r = (xi - n * _LN2_HI) - n * _LN2_LO  # Cody-Waite: exact n ln2 in two parts
        x[i] = c0 + r * (c1 + r * (c2 + r * (c3 + r * (c4 + r * (c5 + r * (c6 + r * c7))))))
        bits[i] = (np.int32(n) + 127) << 23
    scale = bits.view(np.float32)
    for i in range(lo, hi):
        x[i] *= scale[i]


@_jit
def _gelu(x, tmp, bits):
    """x <- x Phi(x) = x (1 + erf(x / sqrt 2)) / 2, x (R, K) (exact GELU; erf by A&S 7.1.26),
    written without branches as max(x, 0) - |x| erfc(|x| / sqrt 2) / 2 so the loops vectorise.
    tmp, bits: scratch of at least x.size."""
    flat = x.reshape(x.size)
    n = flat.shape[0]
    for i in range(n):
        a = flat[i] * _SQRT1_2
        tmp[i] = -a * a
    _exp(tmp, bits, 0, n)
    a1, a2, a3, a4, a5 = _ERF_A
    for i in range(n):
        ax = abs(flat[i])
        t = 1.0 / (1.0 + _ERF_P * _SQRT1_2 * ax)
        erfc = t * (a1 + t * (a2 + t * (a3 + t * (a4 + t * a5)))) * tmp[i]
        flat[i] = max(flat[i], 0.0) - 0.5 * ax * erfc


@_jit
def _affine(x, w, b, out):
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
        _accumulate(x[r], w, out[r])


@_jit
def _accumulate(x, w, out):
    """out += x @ w for one row: x (K,), w (K, N), out (N,)."""
    for k in range(w.shape[0]):
        xk, wk = x[k], w[k]
        for j in range(wk.shape[0]):
            out[j] += xk * wk[j]


@_jit
def _lstm_update(g, c, h, tmp, bits):
    """One LSTM step from the pre-activations g (4H,), PyTorch's gate order (i, f, g, o):
    c <- sigmoid(f) c + sigmoid(i) tanh(g);  h <- sigmoid(o) tanh(c).  tmp, bits: >= 5H."""
    hidden = c.shape[0]
    for j in range(4 * hidden):  # e^{-x} for the sigmoids, e^{-2|x|} for tanh
        tmp[j] = -g[j]
    for j in range(2 * hidden, 3 * hidden):
        tmp[j] = -2.0 * abs(g[j])
    _exp(tmp, bits, 0, 4 * hidden)
    for j in range(hidden):
        e = tmp[2 * hidden + j]
        g_act = math.copysign((1.0 - e) / (1.0 + e), g[2 * hidden + j])
        c[j] = c[j] / (1.0 + tmp[hidden + j]) + g_act / (1.0 + tmp[j])
        tmp[4 * hidden + j] = -2.0 * abs(c[j])
    _exp(tmp, bits, 4 * hidden, 5 * hidden)
    for j in range(hidden):
        e = tmp[4 * hidden + j]
        h[j] = math.copysign((1.0 - e) / (1.0 + e), c[j]) / (1.0 + tmp[3 * hidden + j])


@_jit
def _lstm_layer_step(x, w_in, w_hh, b, layer, hs, cs, g, tmp, bits):
    """Layer ``layer`` of a stacked LSTM, one step on input x (K,) with weights w_in (K, 4H)."""
    for j in range(g.shape[0]):
        g[j] = b[layer, j]
    _accumulate(x, w_in, g)
    _accumulate(hs[layer], w_hh[layer], g)
    _lstm_update(g, cs[layer], hs[layer], tmp, bits)


@_jit
def _embed(xu, w, e0, e1, e2, tmp, bits):
    """e2 = the input embedding of rows xu (R, 17) = (x - origin, u), physical units."""
    _affine(xu, w.emb_xu, w.emb_b, e0)
    _gelu(e0, tmp, bits)
    _affine(e0, w.emb1_w, w.emb1_b, e1)
    _gelu(e1, tmp, bits)
    _affine(e1, w.emb2_w, w.emb2_b, e2)
    _gelu(e2, tmp, bits)


@_jit
def _relative_rows(history, origin_shift, xu, origin):
    """File rows history (M, 17) -> xu (M, 17): (x - origin, u) in the package layout, q
    w-x-y-z unit without sign jumps (as ``predictor.states_from_file``); origin (13,) as
    ``SlungLoadNet.origin`` of the last row."""
    m = history.shape[0]
    parity = 0
    for k in range(m):
        for j in range(17):
            xu[k, j] = history[k, j]
        qx, qy, qz, qw = history[k, 6], history[k, 7], history[k, 8], history[k, 9]
        norm = max(math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz), 1e-12)
        xu[k, 6], xu[k, 7], xu[k, 8], xu[k, 9] = qw / norm, qx / norm, qy / norm, qz / norm
        if k > 0:  # sign flips counted on the unflipped neighbours, as quat_continuous
            sign_prev = -1.0 if parity else 1.0
            dot = 0.0
            for j in range(6, 10):
                dot += xu[k, j] * xu[k - 1, j] * sign_prev
            if dot < 0:
                parity = 1 - parity
            if parity:
                for j in range(6, 10):
                    xu[k, j] = -xu[k, j]
    origin[:] = 0.0
    for i in range(3):
        for j in range(13):
            origin[j] += xu[m - 1, i] * origin_shift[i, j]
    for k in range(m):
        for j in range(13):
            xu[k, j] -= origin[j]


# --- the discrete model, batch 1: a compiled copy of physics.step (see the module doc) ------


@_jit
def _rotation_step(qw, qx, qy, qz, r0, r1, r2):
    """q (x) exp(r / 2), normalised: ``physics.step``'s attitude update for q (w-x-y-z, any
    norm) and the rotation vector r = h omega (rad). roma's ``rotvec_to_unitquat`` (with its
    sinc) and ``quat_product``, then ``state.quat_normalize``; returns (w, x, y, z)."""
    half = 0.5 * math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    if half < 1e-4:  # a Taylor expansion near zero, as roma's sinc (sin(x)/x to round-off)
        sinc = 1.0 - half * half / 6.0 + half**4 / 120.0
    else:
        sinc = math.sin(half) / half
    s = 0.5 * sinc
    dw, dx, dy, dz = math.cos(half), s * r0, s * r1, s * r2
    # Hamilton product: w = pw dw - p.d, v = pw d + dw p + p x d.
    w = qw * dw - (qx * dx + qy * dy + qz * dz)
    x = qw * dx + dw * qx + (qy * dz - qz * dy)
    y = qw * dy + dw * qy + (qz * dx - qx * dz)
    z = qw * dz + dw * qz + (qx * dy - qy * dx)
    norm = max(math.sqrt(w * w + x * x + y * y + z * z), 1e-12)
    return w / norm, x / norm, y / norm, z / norm


@_jit
def _physics_step(xu, aux, c, x_next, aux_next):
    """``physics.step`` for one state: xu (>= 17,) = (x_k (13), u_k (4)) in the package layout
    (q w-x-y-z), aux (6,) = (vL m/s, Omega_L rad/s), c ``VehicleConstants`` -> x_next (13,),
    aux_next (6,). Same formulas as ``physics.accelerations`` and ``physics.step``, in float64
    inside (any float arrays in and out)."""
    h, g, mq, ml, length = c.dt, c.gravity, c.mass_quad, c.mass_load, c.cable_length
    # T R e3: the third column of the rotation of the normalised q (roma's formula).
    qw, qx, qy, qz = float(xu[6]), float(xu[7]), float(xu[8]), float(xu[9])
    norm = max(math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz), 1e-12)
    qw, qx, qy, qz = qw / norm, qx / norm, qy / norm, qz / norm
    thrust = c.thrust_gain * float(xu[13])
    tw = (
        2.0 * (qx * qz + qy * qw) * thrust,
        2.0 * (qy * qz - qx * qw) * thrust,
        (-qx * qx - qy * qy + qz * qz + qw * qw) * thrust,
    )
    xi = (
        (float(xu[10]) - float(xu[0])) / length,
        (float(xu[11]) - float(xu[1])) / length,
        (float(xu[12]) - float(xu[2])) / length,
    )
    rate_sq = float(aux[3]) ** 2 + float(aux[4]) ** 2 + float(aux[5]) ** 2
    along = xi[0] * tw[0] + xi[1] * tw[1] + xi[2] * tw[2]
    t_load = -(ml / (mq + ml)) * along + (ml * mq / (mq + ml)) * length * rate_sq  # tension
    cross = (
        xi[1] * tw[2] - xi[2] * tw[1],
        xi[2] * tw[0] - xi[0] * tw[2],
        xi[0] * tw[1] - xi[1] * tw[0],
    )
    for i in range(3):
        down = g if i == 2 else 0.0
        acc = tw[i] / mq - down + (t_load / mq) * xi[i]
        acc_load = -(t_load / ml) * xi[i] - down
        x_next[i] = xu[i] + h * xu[3 + i] + 0.5 * h * h * acc
        x_next[3 + i] = xu[3 + i] + h * acc
        x_next[10 + i] = xu[10 + i] + h * aux[i] + 0.5 * h * h * acc_load
        aux_next[i] = aux[i] + h * acc_load
        rate_dot = -cross[i] / (mq * length)
        aux_next[3 + i] = (1.0 - c.load_damping) * aux[3 + i] + h * rate_dot
    q = _rotation_step(
        float(xu[6]), float(xu[7]), float(xu[8]), float(xu[9]),
        h * xu[14], h * xu[15], h * xu[16],
    )  # fmt: skip
    for i in range(4):
        x_next[6 + i] = q[i]


@_jit
def _swing_rate(last, r_dot, c, aux):
    """aux[3:6] = Omega_L = xi x r_dot / l, with xi = r / |r| and r = pL - p of the state
    ``last`` (>= 13,) (package layout); r_dot (3,) m/s. float64 inside."""
    r = (
        float(last[10]) - float(last[0]),
        float(last[11]) - float(last[1]),
        float(last[12]) - float(last[2]),
    )
    norm = max(math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2]), 1e-9)
    xi = (r[0] / norm, r[1] / norm, r[2] / norm)
    aux[3] = (xi[1] * r_dot[2] - xi[2] * r_dot[1]) / c.cable_length
    aux[4] = (xi[2] * r_dot[0] - xi[0] * r_dot[2]) / c.cable_length
    aux[5] = (xi[0] * r_dot[1] - xi[1] * r_dot[0]) / c.cable_length


@_jit
def _estimate_load_state(prev, last, c, aux):
    """``load_state.estimate_load_state`` at the later of two consecutive states prev, last
    (>= 13,) (package layout) -> aux (6,) = (vL m/s, Omega_L rad/s): backward differences of
    pL and of r = pL - p over h, Omega_L = xi x r_dot / l with xi = r / |r|. float64 inside."""
    h = c.dt
    r_dot = np.empty(3)
    for i in range(3):
        aux[i] = (float(last[10 + i]) - float(prev[10 + i])) / h
        r_dot[i] = (
            (float(last[10 + i]) - float(last[i])) - (float(prev[10 + i]) - float(prev[i]))
        ) / h
    _swing_rate(last, r_dot, c, aux)


@_jit
def _fit_load_state(xu, m, filters, c, aux):
    """``load_state.fit_load_state`` at history row m - 1 of xu (M, >= 13) -> aux (6,): the
    slopes of least-squares quadratics through the last K = min(M, rows of filters + 2) rows of
    pL and r = pL - p, weights ``filters[K - 3, :K]``; Omega_L = xi x r_dot / l with xi from
    the last row. float64 inside."""
    k = min(m, filters.shape[0] + 2)
    v = np.zeros(3)  # float64 sums, rounded once into aux
    r_dot = np.zeros(3)
    for j in range(k):
        row = xu[m - k + j]
        wgt = filters[k - 3, j]
        for i in range(3):
            v[i] += wgt * float(row[10 + i])
            r_dot[i] += wgt * (float(row[10 + i]) - float(row[i]))
    for i in range(3):
        aux[i] = v[i]
    _swing_rate(xu[m - 1], r_dot, c, aux)


# --- the forward pass ------------------------------------------------------------------------


@_jit
def _forward(xu, origin, pre, future, w, out):
    """One window from ``_relative_rows``' xu (M, 17) and origin (13,), the encoder's layer-0
    input part pre (M, 4H) and future (N, 4) -> out (N, 13), file layout."""
    m, n = xu.shape[0], future.shape[0]
    layers, hidden, gates = w.enc_hh.shape[0], w.enc_hh.shape[1], w.enc_hh.shape[2]
    e_widths = (w.emb_b.shape[0], w.emb1_b.shape[0], w.emb2_b.shape[0])
    size = max(max(e_widths), m * hidden, 5 * hidden, w.head1_b.shape[0])
    tmp = np.empty(size, np.float32)
    bits = np.empty(size, np.int32)

    # Encoder: the stacked LSTM step by step.
    hs = np.zeros((layers, hidden), np.float32)
    cs = np.zeros((layers, hidden), np.float32)
    g = np.empty(gates, np.float32)
    zero_b = np.zeros((layers, gates), np.float32)
    enc = np.empty((m, hidden), np.float32)
    for k in range(m):
        for j in range(gates):
            g[j] = pre[k, j]
        _accumulate(hs[0], w.enc_hh[0], g)
        _lstm_update(g, cs[0], hs[0], tmp, bits)
        for layer in range(1, layers):
            _lstm_layer_step(
                hs[layer - 1], w.enc_ih[layer], w.enc_hh, w.enc_b, layer, hs, cs, g, tmp, bits
            )
        for j in range(hidden):
            enc[k, j] = hs[layers - 1, j]
    keys = np.empty((m, hidden), np.float32)
    _affine(enc, w.att_w, zero_b[0, :hidden].copy(), keys)
    enc_ctx = np.empty((m, gates), np.float32)
    _affine(enc, w.dec_ctx, zero_b[0], enc_ctx)

    # Decoder: one row through the same kernels, feeding back its own prediction.
    d0 = np.empty((1, e_widths[0]), np.float32)
    d1 = np.empty((1, e_widths[1]), np.float32)
    d2 = np.empty((1, e_widths[2]), np.float32)
    row = np.empty((1, 17), np.float32)
    for j in range(13):
        row[0, j] = xu[m - 1, j]
    query = np.empty(hidden, np.float32)
    scores = np.empty(m, np.float32)
    y1 = np.empty((1, w.head1_b.shape[0]), np.float32)
    y2 = np.empty((1, w.head2_b.shape[0]), np.float32)
    y3 = np.empty((1, 13), np.float32)
    # Physics-step network: the load state a_{M-1} and f's outputs (unused otherwise).
    aux = np.zeros(6, np.float32)
    aux_next = np.empty(6, np.float32)
    x_next = np.empty(13, np.float32)
    if w.physics_step and w.load_filters.shape[0] > 0:
        _fit_load_state(xu, m, w.load_filters, w.vehicle, aux)
    elif w.physics_step:
        _estimate_load_state(xu[m - 2], xu[m - 1], w.vehicle, aux)
    for step in range(n):
        for j in range(4):
            row[0, 13 + j] = xu[m - 1, 13 + j] if step == 0 else future[step - 1, j]
        # Attention weights over the history from the top layer's hidden state.
        query[:] = 0.0
        _accumulate(hs[layers - 1], w.att_u, query)
        for k in range(m):
            for j in range(hidden):
                tmp[k * hidden + j] = -2.0 * abs(keys[k, j] + query[j])
        _exp(tmp, bits, 0, m * hidden)
        for k in range(m):
            s = 0.0
            for j in range(hidden):
                e = tmp[k * hidden + j]
                s += w.att_v[j] * math.copysign((1.0 - e) / (1.0 + e), keys[k, j] + query[j])
            scores[k] = s
        scores -= scores.max()
        _exp(scores, bits, 0, m)
        scores /= scores.sum()

        _embed(row, w, d0, d1, d2, tmp, bits)
        for j in range(gates):
            g[j] = w.dec_b[0, j]
        _accumulate(d2[0], w.dec_emb, g)
        _accumulate(hs[0], w.dec_hh[0], g)
        _accumulate(scores, enc_ctx, g)  # the context's share of layer 0
        _lstm_update(g, cs[0], hs[0], tmp, bits)
        for layer in range(1, layers):
            _lstm_layer_step(
                hs[layer - 1], w.dec_ih[layer], w.dec_hh, w.dec_b, layer, hs, cs, g, tmp, bits
            )

        _affine(hs[layers - 1 : layers], w.head1_w, w.head1_b, y1)
        _gelu(y1, tmp, bits)
        _affine(y1, w.head2_w, w.head2_b, y2)
        _gelu(y2, tmp, bits)
        _affine(y2, w.head3_w, w.head3_b, y3)
        if w.physics_step:  # x_{k+1} = f(x_k, u_k, a_k) + delta_std * out_k
            _physics_step(row[0], aux, w.vehicle, x_next, aux_next)
            aux[:] = aux_next
            for j in range(13):
                row[0, j] = x_next[j] + y3[0, j]
        else:
            for j in range(13):
                row[0, j] = row[0, j] + y3[0, j] if w.residual else y3[0, j] + w.add_mean[j]

        # Output: absolute positions, unit quaternion, x-y-z-w order.
        qw, qx, qy, qz = row[0, 6], row[0, 7], row[0, 8], row[0, 9]
        norm = max(math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz), 1e-12)
        for j in range(13):
            out[step, j] = row[0, j] + origin[j]
        out[step, 6], out[step, 7] = qx / norm, qy / norm
        out[step, 8], out[step, 9] = qz / norm, qw / norm


__all__ = [
    "COMPILED_ARCHITECTURES",
    "PARITY_TOLERANCE",
    "CompiledPredictor",
    "FoldedWeights",
    "fold",
    "unsupported",
]
