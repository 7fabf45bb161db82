"""Batch-1 prediction compiled with Numba: the network's forward pass for a control loop.

    fast = CompiledPredictor(Predictor.from_checkpoint("runs/proposed"))
    states = fast.predict(history, future_inputs)        # same call and result as Predictor

Why a third path beside eager torch and the ONNX export: at batch 1 the decoder is ~60 tiny
operators per horizon step, and every runtime that dispatches operators one at a time pays
for each (~7 us in eager torch, ~1 us in ONNX Runtime) more than the arithmetic
(docs/deployment.md). Here each forward pass is one compiled call (``_forward``): element-wise
work is fused into the loops around the matrix-vector products (``kernels``), and nothing is
allocated per step. The weights are ``fold``'s, laid out (in, out) for these loops; the
attention context enters the decoder's first LSTM layer only through its context columns, so
the encoder outputs are projected by them once per window and the context is never formed.

The physics-step network (``models.physics_step.PhysicsStepNet``) compiles too: the same
loop, whose decoder step is x_{k+1} = f(x_k, u_k, a_k) + delta_std * out_k instead of
x_k + delta_std * out_k, with the load state a = (vL, Omega_L) estimated from the last history
rows and carried by f (``physics``, the compiled copy of ``physics.step`` and the load-state
estimates).

Float32 throughout (float64 inside the physics step). Predictions agree with
``Predictor.predict`` to ~1e-6 (tested against ``PARITY_TOLERANCE``); they are not
bit-identical (different summation order).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ...config import ESTIMATE_MIN_STEPS
from ...layout import (
    AUX_DIM,
    HISTORY_DIM,
    INPUT_DIM,
    POS,
    QUAT,
    STATE_DIM,
    THRUST,
    WXYZ_TO_XYZW,
    XYZW_TO_WXYZ,
)
from ...physics import VehicleConstants
from ...state import from_heading_frame, heading_turn, to_heading_frame
from ..inputs import check_inputs, unbatch
from ..predictor import PARITY_TOLERANCE, Predictor, torch_threads
from .fold import fold, unsupported_architecture
from .kernels import (
    accumulate,
    affine,
    attention_row,
    encode_rows,
    gelu,
    jit,
    lstm_cell,
    lstm_layer,
)
from .physics import adapted_constants, estimate_load_state, fit_load_state, physics_step
from .weights import PHYSICS_STEP, RESIDUAL, FoldedWeights, first_bias

_P, _Q, _U = POS.start, QUAT.start, STATE_DIM  # rows of an (x, u) row: position, q, u
# File columns of the quaternion's w, x, y, z (the file layout is x-y-z-w), and the package
# components of the file's x, y, z, w.
_FILE_QW, _FILE_QX, _FILE_QY, _FILE_QZ = (QUAT.start + i for i in XYZW_TO_WXYZ)
_TO_FILE = WXYZ_TO_XYZW
# State columns: file = package[..., _PACKAGE_TO_FILE], package = file[..., _FILE_TO_PACKAGE].
_PACKAGE_TO_FILE = [*range(_Q), *(_Q + i for i in WXYZ_TO_XYZW), *range(QUAT.stop, STATE_DIM)]
_FILE_TO_PACKAGE = [*range(_Q), *(_Q + i for i in XYZW_TO_WXYZ), *range(QUAT.stop, STATE_DIM)]
_THRUST = STATE_DIM + THRUST.start  # an (x, u) row's thrust column


class _Rows(NamedTuple):
    """``FoldedWeights`` laid out for the batch-1 pass: matrices (in, out), so that each
    product is a loop over the outputs (``kernels.accumulate``); three embedding and three
    head layers (the paper's shape)."""

    emb0_w: np.ndarray  # (17, E0) on (x - origin, u), physical units
    emb0_b: np.ndarray
    emb1_w: np.ndarray
    emb1_b: np.ndarray
    emb2_w: np.ndarray  # (E1, E)
    emb2_b: np.ndarray
    enc_ih: np.ndarray  # (L, H, G)
    enc_hh: np.ndarray  # (L, H, G)
    enc_b: np.ndarray  # (L, G)
    att_w: np.ndarray  # (H, H)
    att_u: np.ndarray  # (H, H)
    att_v: np.ndarray  # (H,)
    dec_ctx: np.ndarray  # (H, G)
    dec_emb: np.ndarray  # (E, G)
    dec_ih: np.ndarray  # (L, H, G)
    dec_hh: np.ndarray  # (L, H, G)
    dec_b: np.ndarray  # (L, G)
    head0_w: np.ndarray  # (H, K0)
    head0_b: np.ndarray
    head1_w: np.ndarray
    head1_b: np.ndarray
    head2_w: np.ndarray  # (K1, 13)
    head2_b: np.ndarray
    add_mean: np.ndarray  # (13,)
    mode: int  # ``fold.RESIDUAL``, ``ABSOLUTE`` or ``PHYSICS_STEP``
    origin_shift: np.ndarray  # (3, 13)
    vehicle: VehicleConstants
    load_filters: np.ndarray


def _rows(w: FoldedWeights) -> _Rows:
    t = lambda a: np.ascontiguousarray(a.T)  # noqa: E731
    stack = lambda a: np.ascontiguousarray(a.transpose(0, 2, 1))  # noqa: E731
    (e0, e0b), (e1, e1b), (e2, e2b) = w.embed
    (h0, h0b), (h1, h1b), (h2, h2b) = w.head
    return _Rows(
        t(e0), e0b, t(e1), e1b, t(e2), e2b,
        stack(w.enc_ih), stack(w.enc_hh), w.enc_b,
        t(w.att_w), t(w.att_u), w.att_v,
        t(w.dec_ctx), t(w.dec_emb), stack(w.dec_ih), stack(w.dec_hh), w.dec_b,
        t(h0), h0b, t(h1), h1b, t(h2), h2b,
        w.add_mean, w.mode, w.origin_shift, w.vehicle, w.load_filters,
    )  # fmt: skip


def unsupported(model: nn.Module) -> str | None:
    """Why ``CompiledPredictor`` cannot compile ``model`` (its architecture or its layer
    structure), or None when it can."""
    reason = unsupported_architecture(model)
    if reason is not None:
        return reason
    cfg = model.config
    if len(cfg.embed_sizes) != 3 or len(cfg.head_sizes) != 3:
        return (
            "CompiledPredictor supports three embedding and three head layers (the paper's "
            f"shape); got embed_sizes={cfg.embed_sizes}, head_sizes={cfg.head_sizes}"
        )
    return None


class CompiledPredictor:
    """``Predictor.predict`` as one compiled call per window (numpy in, numpy out).

    Same arguments, checks and result as ``Predictor.predict`` (file layout, quaternion
    x-y-z-w, float64 out; M and ``threads`` as the wrapped ``Predictor``'s). Single-threaded
    by default; windows of a batch run one after another, so it is meant for batch 1 (larger
    batches are faster on the torch or ONNX paths). ``weights``: the ``FoldedWeights``.
    """

    def __init__(self, predictor: Predictor, *, warm_up: bool = True) -> None:
        reason = unsupported(predictor.model)
        if reason is not None:
            raise ValueError(reason)
        self.predictor = predictor
        self.weights = w = fold(predictor.model)
        self._w = rows = _rows(w)
        t = torch.from_numpy  # shares memory with the folded arrays
        self._embedding = [  # the first layer's bias is each window's (``_for_window``)
            (t(rows.emb0_w), None),
            (t(rows.emb1_w), t(rows.emb1_b)),
            (t(rows.emb2_w), t(rows.emb2_b)),
        ]
        self._enc_emb, self._enc_b0 = t(np.ascontiguousarray(w.enc_emb.T)), t(w.enc_b[0])
        if warm_up:  # compile (or load from Numba's cache) now, not in the first control step
            history = np.zeros((predictor.window.history, HISTORY_DIM), dtype=np.float32)
            history[:, _FILE_QW] = 1.0  # unit quaternion
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
        w = self._w
        batch, m = hist.shape[:2]
        least = ESTIMATE_MIN_STEPS if self.weights.constants == "window" else 2
        if w.mode == PHYSICS_STEP and m < least:  # as PhysicsStepNet.start_rollout
            raise ValueError(
                f"CompiledPredictor.predict: the {self.weights.architecture!r} network needs "
                f"M >= {least} history rows to estimate the load state (vL, Omega_L)"
                + (" and its constants" if least > 2 else "")
                + f"; got M = {m}"
            )
        xu = np.empty((batch, m, HISTORY_DIM), dtype=np.float32)
        origin = np.empty((batch, STATE_DIM), dtype=np.float32)
        for b in range(batch):
            _relative_rows(hist[b], w.origin_shift, xu[b], origin[b])
        turns = self._to_heading_frame(xu, origin)
        windows = [self._for_window(xu[b]) for b in range(batch)]
        with torch_threads(p.threads):  # the only torch work: one matrix product
            pre = self._encoder_inputs(xu, np.stack([r.emb0_b for r in windows]))
        out = np.empty((batch, fut.shape[1], STATE_DIM), dtype=np.float32)
        for b in range(batch):
            _forward(xu[b], origin[b], pre[b], fut[b], windows[b], out[b])
        if turns is not None:  # back to the world frame, in the file layout
            states = torch.from_numpy(out[..., _FILE_TO_PACKAGE].astype(np.float64))
            out = from_heading_frame(states, turns).numpy()[..., _PACKAGE_TO_FILE]
        return unbatch(out, single)

    def _to_heading_frame(self, xu: np.ndarray, origin: np.ndarray) -> Tensor | None:
        """For a network that sees the heading frame (``ModelConfig.heading_frame``): the rows
        xu (B, M, 17, package layout, relative to ``origin``) and the origins (B, 13) turned in
        place by each window's heading, as ``SlungLoadNet.forward`` turns them (the same torch
        helpers); the turns (B, 13, 13), or None for a world-frame network."""
        last = torch.from_numpy(xu[:, -1, :STATE_DIM].astype(np.float64))  # (B, 13)
        twist = self.predictor.model.heading(last)
        if twist is None:
            return None
        turns = heading_turn(twist)
        rows = torch.from_numpy(xu[..., :STATE_DIM].astype(np.float64))
        xu[..., :STATE_DIM] = to_heading_frame(rows, turns).numpy()
        here = torch.from_numpy(origin.astype(np.float64)).unsqueeze(1)  # (B, 1, 13)
        origin[:] = to_heading_frame(here, turns)[:, 0].numpy()
        return turns

    def _for_window(self, xu: np.ndarray) -> _Rows:
        """The rows for this window (M, 17): f's constants the network's, or, adapting to its
        load, the window's own estimate (``physics.adapted_constants``); the first embedding
        bias with them (``fold.first_bias``) for a network that sees them."""
        w = self._w
        if self.weights.constants != "window":
            return w
        vehicle = adapted_constants(xu[:, :STATE_DIM], xu[:, _THRUST], w.vehicle)
        return w._replace(vehicle=vehicle, emb0_b=first_bias(self.weights, vehicle))

    def _encoder_inputs(self, xu: np.ndarray, bias0: np.ndarray) -> np.ndarray:
        """(B, M, 17) rows -> (B, M, 4H): embedding and encoder layer 0's input part, with each
        window's first embedding bias ``bias0`` (B, E0).

        Matrix-matrix work over the M history rows, done by torch's BLAS and vectorised GELU
        (several times faster here than the compiled loops); the recurrent part stays compiled.
        """
        batch, m, _ = xu.shape
        with torch.inference_mode():
            e = torch.from_numpy(xu) @ self._embedding[0][0]  # (B, M, E0)
            e = F.gelu(e + torch.from_numpy(bias0).unsqueeze(1)).reshape(batch * m, -1)
            for weight, bias in self._embedding[1:]:
                e = F.gelu(torch.addmm(bias, e, weight))
            pre = torch.addmm(self._enc_b0, e, self._enc_emb)
        return pre.reshape(batch, m, -1).numpy()


# --- the compiled pass ----------------------------------------------------------------------


@jit
def _relative_rows(history, origin_shift, xu, origin):
    """File rows history (M, 17) -> xu (M, 17): (x - origin, u) in the package layout, q
    w-x-y-z unit without sign jumps (as ``predictor.states_from_file``); origin (13,) as
    ``SlungLoadNet.origin`` of the last row."""
    m = history.shape[0]
    parity = 0
    for k in range(m):
        for j in range(HISTORY_DIM):
            xu[k, j] = history[k, j]
        qw, qx = history[k, _FILE_QW], history[k, _FILE_QX]
        qy, qz = history[k, _FILE_QY], history[k, _FILE_QZ]
        norm = max(math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz), 1e-12)
        xu[k, _Q], xu[k, _Q + 1], xu[k, _Q + 2], xu[k, _Q + 3] = (
            qw / norm, qx / norm, qy / norm, qz / norm
        )  # fmt: skip
        if k > 0:  # sign flips counted on the unflipped neighbours, as quat_continuous
            sign_prev = -1.0 if parity else 1.0
            dot = 0.0
            for j in range(_Q, _Q + 4):
                dot += xu[k, j] * xu[k - 1, j] * sign_prev
            if dot < 0:
                parity = 1 - parity
            if parity:
                for j in range(_Q, _Q + 4):
                    xu[k, j] = -xu[k, j]
    origin[:] = 0.0
    for i in range(3):
        for j in range(STATE_DIM):
            origin[j] += xu[m - 1, _P + i] * origin_shift[i, j]
    for k in range(m):
        for j in range(STATE_DIM):
            xu[k, j] -= origin[j]


@jit
def _forward(xu, origin, pre, future, w, out):
    """One window from ``_relative_rows``' xu (M, 17) and origin (13,), the encoder's layer-0
    input part pre (M, 4H) and future (N, 4) -> out (N, 13), file layout."""
    m, n = xu.shape[0], future.shape[0]
    layers, hidden, gates = w.enc_hh.shape[0], w.enc_hh.shape[1], w.enc_hh.shape[2]
    hs = np.zeros((layers, hidden), np.float32)
    cs = np.zeros((layers, hidden), np.float32)
    keys, enc_ctx = _encode(pre, w, hs, cs)
    row = np.empty((1, HISTORY_DIM), np.float32)  # the decoder's (x_k - origin, u_k)
    for j in range(STATE_DIM):
        row[0, j] = xu[m - 1, j]
    embedded = (
        np.empty((1, w.emb0_b.shape[0]), np.float32),
        np.empty((1, w.emb1_b.shape[0]), np.float32),
        np.empty((1, w.emb2_b.shape[0]), np.float32),
    )
    heads = (
        np.empty((1, w.head0_b.shape[0]), np.float32),
        np.empty((1, w.head1_b.shape[0]), np.float32),
        np.empty((1, STATE_DIM), np.float32),
    )
    query, scores = np.empty(hidden, np.float32), np.empty(m, np.float32)
    g = np.empty(gates, np.float32)
    aux = _initial_load_state(xu, w)
    aux_next, x_next = np.empty_like(aux), np.empty(STATE_DIM, np.float32)
    for step in range(n):
        for j in range(INPUT_DIM):
            row[0, _U + j] = xu[m - 1, _U + j] if step == 0 else future[step - 1, j]
        _decoder_step(row, w, hs, cs, keys, enc_ctx, embedded, query, scores, g)
        _head(hs[layers - 1 : layers], w, heads)
        _next_state(row[0], heads[2][0], aux, w, x_next, aux_next)
        _output(row[0], origin, out[step])


@jit
def _encode(pre, w, hs, cs):
    """The encoder over the M rows (its state left in hs, cs); returns the attention keys
    (H, M) and the encoder outputs through the decoder's context columns (M, 4H)."""
    m, hidden, gates = pre.shape[0], hs.shape[1], pre.shape[1]
    enc = np.empty((m, hidden), np.float32)
    encode_rows(pre, w.enc_ih, w.enc_hh, w.enc_b, hs, cs, enc)
    rows = np.empty((m, hidden), np.float32)
    affine(enc, w.att_w, np.zeros(hidden, np.float32), rows)
    keys = np.empty((hidden, m), np.float32)
    for k in range(m):
        for j in range(hidden):
            keys[j, k] = rows[k, j]
    enc_ctx = np.empty((m, gates), np.float32)
    affine(enc, w.dec_ctx, np.zeros(gates, np.float32), enc_ctx)
    return keys, enc_ctx


@jit
def _initial_load_state(xu, w):
    """The physics-step network's a_{M-1} from the history rows xu (M, >= 13) (float32; zero
    for the other modes)."""
    m = xu.shape[0]
    aux = np.zeros(AUX_DIM, np.float32)
    if w.mode == PHYSICS_STEP and w.load_filters.shape[0] > 0:
        fit_load_state(xu, m, w.load_filters, w.vehicle, aux)
    elif w.mode == PHYSICS_STEP:
        estimate_load_state(xu[m - 2], xu[m - 1], w.vehicle, aux)
    return aux


@jit
def _decoder_step(row, w, hs, cs, keys, enc_ctx, embedded, query, scores, g):
    """One decoder step on row (1, 17): the attention weights over the history from the top
    layer's hidden state, the embedding of row, the stacked LSTM cell (hs, cs in place)."""
    layers = hs.shape[0]
    query[:] = 0.0
    accumulate(hs[layers - 1], w.att_u, query)
    attention_row(query, keys, w.att_v, scores)
    e0, e1, e2 = embedded
    affine(row, w.emb0_w, w.emb0_b, e0)
    gelu(e0)
    affine(e0, w.emb1_w, w.emb1_b, e1)
    gelu(e1)
    affine(e1, w.emb2_w, w.emb2_b, e2)
    gelu(e2)
    for j in range(g.shape[0]):
        g[j] = w.dec_b[0, j]
    accumulate(e2[0], w.dec_emb, g)
    accumulate(hs[0], w.dec_hh[0], g)
    accumulate(scores, enc_ctx, g)  # the context's share of layer 0
    lstm_cell(g, cs[0], hs[0])
    for layer in range(1, layers):
        lstm_layer(
            hs[layer - 1], w.dec_ih[layer], w.dec_hh[layer], w.dec_b[layer], cs[layer], hs[layer], g
        )


@jit
def _head(h, w, heads):
    """The head on the top hidden state h (1, H): heads[2] (1, 13), the scaled state rows."""
    y0, y1, y2 = heads
    affine(h, w.head0_w, w.head0_b, y0)
    gelu(y0)
    affine(y0, w.head1_w, w.head1_b, y1)
    gelu(y1)
    affine(y1, w.head2_w, w.head2_b, y2)


@jit
def _next_state(row, y, aux, w, x_next, aux_next):
    """row (17,)'s state x_k -> x_{k+1} from the head's output y (13,): f(x_k, u_k, a_k) + y
    (the physics step, a advancing in place), x_k + y (residual) or y + add_mean (absolute)."""
    if w.mode == PHYSICS_STEP:
        physics_step(row, aux, w.vehicle, x_next, aux_next)
        aux[:] = aux_next
        for j in range(STATE_DIM):
            row[j] = x_next[j] + y[j]
    elif w.mode == RESIDUAL:
        for j in range(STATE_DIM):
            row[j] = row[j] + y[j]
    else:
        for j in range(STATE_DIM):
            row[j] = y[j] + w.add_mean[j]


@jit
def _output(row, origin, out):
    """The decoder's state row (>= 13,) -> out (13,): absolute positions, unit quaternion,
    file layout (x-y-z-w)."""
    qw, qx, qy, qz = row[_Q], row[_Q + 1], row[_Q + 2], row[_Q + 3]
    norm = max(math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz), 1e-12)
    for j in range(STATE_DIM):
        out[j] = row[j] + origin[j]
    for i in range(4):
        out[_Q + i] = row[_Q + _TO_FILE[i]] / norm


__all__ = ["PARITY_TOLERANCE", "CompiledPredictor", "unsupported"]
