"""The MPC's candidate rollouts on numpy and Numba alone: what the compiled backend runs, in the
full install and onboard alike (no torch).

    model = NetworkColumns(folded, history=50)             # a ``fold``ed network
    states = model.numpy_candidates(x_hist, u_past, plans)  # (K, N, 13) float64
    model = PhysicsColumns(VehicleConstants.of(params))     # the discrete model, float64

``NetworkColumns`` runs a network's candidates in float32 on the weights of the one fold
(``weights.FoldedWeights``: standardisation folded into the first layer, physical units relative
to the last position, the head's Linears joined, the residual gain in the last layer). The K
candidates are the columns of every work array (features x K), so that each kernel's inner loop
runs over the candidates and each product is W (out, in) @ X (in, K), numpy's BLAS writing into
preallocated arrays. As in the eager ``forward_candidates`` the encoder runs once over the M - 1
shared rows (batch 1) and only its last step at batch K; the attention works on the shared
rows' keys and context projections once. What a step multiplies is stacked so that each LSTM
layer is one product: layer 0's [context | embedding | recurrent] weights on the rows [attention
weights; embedding; h_0], a layer above its [input | recurrent] weights on [h_{i-1}; h_i], the
biases added inside the cell's kernel.

``PhysicsColumns`` rolls the discrete model out for the K candidates in one compiled call
(``physics.physics_rollout``), float64, with the constants fixed or estimated from the history.

Both equal the eager torch models to float32 rounding for the network and to round-off for the
physics (tests: ``test_compiled_batched.py``); they are the numpy ``CandidateModel`` the MPC
calls (``control.mppi``): ``predict_candidates`` is ``numpy_candidates``.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from threadpoolctl import ThreadpoolController

from ...config import ADAPT_PRIOR_WEIGHT, VehicleParams
from ...layout import AUX_DIM, INPUT_DIM, LOAD_POS, POS, QUAT, STATE_DIM
from ...vehicle_constants import VehicleConstants
from ..members import members_mean, members_novel
from .kernels import attention_cols, bias_gelu, encode_rows, jit, lstm_cols_add, lstm_cols_bias
from .physics import (
    estimate_load_state,
    fit_load_state,
    history_constants,
    physics_rollout,
    physics_step_columns,
)
from .weights import ABSOLUTE, PHYSICS_STEP, FoldedWeights, first_bias, heading_turn

_Q = QUAT.start
DATASET, WINDOW = "dataset", "window"  # ``config.NETWORK_CONSTANTS``: f's constants


@functools.cache
def _blas() -> ThreadpoolController:
    """numpy's BLAS, whose threads a call limits (made once: finding the libraries takes ~1 ms,
    a limit ~20 us)."""
    return ThreadpoolController().select(user_api="blas")


def hovering(
    m: int, k: int, n: int, vehicle: VehicleConstants
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A candidates call at (M, K, N) = (m, k, n) of a vehicle hovering still with its load
    below: x_hist (m, 13), u_past (m-1, 4) and plans (k, n, 4) all at hover thrust. A still
    history reads no load: estimates from it may be nan (call under ``np.errstate``)."""
    x = np.zeros(STATE_DIM)
    x[_Q] = 1.0
    x[LOAD_POS.start + 2] = -vehicle.cable_length
    hover = np.array([(vehicle.mass_quad + vehicle.mass_load) * vehicle.gravity, 0.0, 0.0, 0.0])
    return np.tile(x, (m, 1)), np.tile(hover, (m - 1, 1)), np.tile(hover, (k, n, 1))


def warm_up(model, m: int, k: int, n: int, vehicle: VehicleConstants) -> None:
    """One call of ``model.numpy_candidates`` on ``hovering``'s inputs: Numba compiles (or
    loads from its cache) every kernel now, and the work arrays are made, rather than in the
    first control step (the MPC's ``prepare``)."""
    with np.errstate(all="ignore"):
        model.numpy_candidates(*hovering(m, k, n, vehicle))


def check_arrays(x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray, history: int) -> None:
    """The candidates call's shapes: x_hist (M, 13), u_past (M-1, 4), plans (K, N, 4) with K,
    N >= 1 and M = ``history``; anything else is a ``ValueError`` naming the array."""
    x_hist, u_past, plans = (np.asarray(a) for a in (x_hist, u_past, plans))
    if x_hist.shape != (history, STATE_DIM):
        raise ValueError(f"x_hist must be ({history}, {STATE_DIM}), got {x_hist.shape}")
    if u_past.shape != (history - 1, INPUT_DIM):
        raise ValueError(f"u_past must be ({history - 1}, {INPUT_DIM}), got {u_past.shape}")
    if plans.ndim != 3 or plans.shape[2] != INPUT_DIM or min(plans.shape[:2]) < 1:
        raise ValueError(f"plans must be (K, N, {INPUT_DIM}) with K, N >= 1, got {plans.shape}")


@dataclass
class PhysicsColumns:
    """The discrete model's K candidates in one compiled float64 loop, the load state estimated
    from the last two measured states; constants "dataset" (``vehicle``) or "window" (the
    history's own cable length and load mass, ``physics.history_constants``, with the mass
    prior ``prior_weight``)."""

    vehicle: VehicleConstants
    constants: str = DATASET
    prior_weight: float = ADAPT_PRIOR_WEIGHT
    history: int = 2
    name: str = "physics"
    numpy: ClassVar[bool] = True  # the MPC calls ``predict_candidates`` with arrays
    horizon: ClassVar[None] = None  # any N
    # an exported file's (``archive.load_columns``): the run's constants and the sidecar
    params: VehicleParams | None = None
    meta: dict | None = None

    def __post_init__(self) -> None:
        if self.constants not in (DATASET, WINDOW):
            raise ValueError(
                f"the compiled physics predicts candidates with constants 'dataset' or "
                f"'window', not {self.constants!r}"
            )

    def numpy_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """x_hist (M, 13), u_past (M-1, 4), plans (K, N, 4) -> states (K, N, 13) float64."""
        vehicle = self.vehicle
        if self.constants == WINDOW:
            vehicle = history_constants(x_hist, u_past, vehicle, self.prior_weight)
        x = np.ascontiguousarray(np.asarray(x_hist)[-2:], np.float64)
        aux = np.empty(AUX_DIM, np.float64)
        estimate_load_state(x[0], x[1], vehicle, aux)
        u = np.ascontiguousarray(plans, np.float64)
        out = np.empty((*u.shape[:2], STATE_DIM), np.float64)
        physics_rollout(x[1], aux, u, vehicle, out)
        return out

    def predict_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """``numpy_candidates`` with the shapes checked (``check_arrays``)."""
        check_arrays(x_hist, u_past, plans, np.asarray(x_hist).shape[0])
        return self.numpy_candidates(x_hist, u_past, plans)

    def prepare(self, m: int, k: int, n: int) -> None:
        """Compile before the first control step (``warm_up``; the MPC calls it when built)."""
        warm_up(self, max(m, 2), k, n, self.vehicle)


class EnsembleColumns:
    """An ensemble's rollouts (``NetworkColumns`` members of one history M): the members'
    mean as the MPC's ``predict_candidates``, each member's as ``predict_candidates_members``
    (``MPCConfig.risk``). calibration: its ``models.ensemble.Calibration`` as a dict (from the
    exported file), or None."""

    numpy = True
    horizon = None  # any N
    params: VehicleParams | None = None
    meta: dict | None = None

    def __init__(
        self, members: list[NetworkColumns], name: str = "ensemble", calibration: dict | None = None
    ) -> None:
        histories = {m.history for m in members}
        if len(members) < 2 or len(histories) != 1:
            raise ValueError(f"an ensemble needs >= 2 members of one history M, got {histories}")
        self.members, self.name, self.calibration = tuple(members), name, calibration
        self.history = histories.pop()

    def numpy_candidates_members(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """(E, K, N, 13) float64: each member's ``numpy_candidates``."""
        return np.stack([m.numpy_candidates(x_hist, u_past, plans) for m in self.members])

    def numpy_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """(K, N, 13): the members' mean (``members_mean``)."""
        return members_mean(self.numpy_candidates_members(x_hist, u_past, plans))

    def predict_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        check_arrays(x_hist, u_past, plans, self.history)
        return self.numpy_candidates(x_hist, u_past, plans)

    def predict_candidates_members(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        check_arrays(x_hist, u_past, plans, self.history)
        return self.numpy_candidates_members(x_hist, u_past, plans)

    def prepare(self, m: int, k: int, n: int) -> None:
        for member in self.members:
            member.prepare(m, k, n)

    def novel(self, members: np.ndarray, shift: np.ndarray | None = None) -> np.ndarray:
        """``members_novel`` under this ensemble's calibration."""
        return members_novel(members, self.calibration, shift)


class _Work:
    """Float32 work arrays for K candidates in columns, and the stacked weights' inputs."""

    def __init__(self, w: FoldedWeights, shared: int, k: int) -> None:
        layers, gates, hidden = w.dec_hh.shape
        emb = w.dec_emb.shape[1]
        self.shared, self.k = shared, k
        self.xu = np.zeros((STATE_DIM + INPUT_DIM, k), np.float32)
        self.embed = [np.zeros((weight.shape[0], k), np.float32) for weight, _ in w.embed[:-1]]
        self.head = [np.zeros((weight.shape[0], k), np.float32) for weight, _ in w.head]
        # layer 0's rows: [attention weights (M-1); embedding (E); h (L x H)]
        self.rows = np.zeros((shared + emb + layers * hidden, k), np.float32)
        self.weights = self.rows[:shared]
        self.embed.append(self.rows[shared : shared + emb])
        self.h = self.rows[shared + emb :].reshape(layers, hidden, k)
        # layer i >= 1's rows [h_{i-1}; h_i]: contiguous views of h
        self.pairs = [self.h[i - 1 : i + 1].reshape(2 * hidden, k) for i in range(1, layers)]
        self.c = np.zeros((layers, hidden, k), np.float32)
        self.gates = np.zeros((gates, k), np.float32)
        self.query = np.zeros((hidden, k), np.float32)
        self.keys_last = np.zeros((hidden, k), np.float32)
        self.ctx_last = np.zeros((gates, k), np.float32)
        self.ctx_part = np.zeros((gates, k), np.float32)  # b_0 + the last row's context share
        self.aux = np.zeros((AUX_DIM, k), np.float64)


class NetworkColumns:
    """A folded network's candidates on numpy's BLAS and compiled kernels, float32 (see the
    module). folded: ``fold.fold(net)`` (or ``archive.load_columns``); history: its M;
    threads: numpy's BLAS threads during a call (default one, as the ONNX session's and
    torch's: at these sizes a second thread on a busy core is slower, and the vehicle's other
    work needs the core), set around each call and restored after it (threadpoolctl)."""

    numpy = True  # the MPC calls ``predict_candidates`` with arrays
    horizon = None  # any N
    # an exported file's (``archive.load_columns``): the run's constants and the sidecar
    params: VehicleParams | None = None
    meta: dict | None = None

    def __init__(
        self, folded: FoldedWeights, history: int, name: str = "network", threads: int = 1
    ) -> None:
        if history < 2:
            raise ValueError(f"a network's candidates need a history M >= 2, got {history}")
        self.folded = w = folded
        self.history, self.name, self.constants = history, name, folded.constants
        self.threads = threads
        self._work: _Work | None = None
        rows = lambda a: np.ascontiguousarray(a.transpose(0, 2, 1))  # noqa: E731
        self._encoder_rows = (rows(w.enc_ih), rows(w.enc_hh), w.enc_b)  # (in, out) matrices
        layers = w.dec_hh.shape[0]
        # the stacked products (see the module): layer 0 on [weights; embedding; h_0] with its
        # context columns appended per call (they depend on the shared rows), layers above on
        # [h_{i-1}; h_i]
        self._upper = [np.ascontiguousarray(np.concatenate([w.dec_ih[i], w.dec_hh[i]], 1))
                       for i in range(1, layers)]  # fmt: skip
        self._keys = np.zeros((0, 0), np.float32)  # the shared rows' keys, per call

    def numpy_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """x_hist (M, 13), u_past (M-1, 4), plans (K, N, 4) -> states (K, N, 13) float64
        (unit quaternions); float64 or float32 in."""
        with _blas().limit(limits=self.threads):
            return self._rollout(x_hist, u_past, plans)

    def _rollout(self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray) -> np.ndarray:
        w = self.folded
        x = np.asarray(x_hist, np.float64)
        turn = heading_turn(w, x[-1, QUAT])
        if turn is not None:
            x = x @ turn  # the heading frame (``state.to_heading_frame``)
        origin = x[-1, POS] @ w.origin_shift.astype(np.float64)  # (13,)
        x_rel = x - origin
        u_cols = np.ascontiguousarray(np.asarray(plans).transpose(1, 2, 0), np.float32)  # (N, 4, K)
        n, _, k = u_cols.shape
        b = self._work_for(x.shape[0] - 1, k)
        vehicle, bias0 = w.vehicle, w.embed[0][1]
        if self.constants == WINDOW:  # the history's own, and the embedding's bias with them
            vehicle = history_constants(x_rel, u_past, w.vehicle)
            bias0 = first_bias(w, vehicle)
        self._load_state(x_rel, b.aux, vehicle)
        b.xu[:STATE_DIM] = x_rel[-1, :, None]
        b.xu[STATE_DIM:] = u_cols[0]
        layer0 = self._encode(x_rel, np.asarray(u_past), b, bias0)
        out = np.empty((k, n, STATE_DIM), np.float64)
        no_input = np.empty((INPUT_DIM, 0), np.float32)
        head_w, head_b = w.head[-1]
        for step in range(n):
            if step > 0:  # step 0's embedding is the last encoder step's
                self._embed(b.xu, b.embed, bias0)
            self._decoder_step(b, layer0)
            self._head(b)
            u_next = u_cols[step + 1] if step + 1 < n else no_input
            _next_columns(
                b.xu, b.head[-1], head_b, b.aux, w.mode, w.add_mean, vehicle, u_next, origin, out,
                step,
            )  # fmt: skip
        if turn is not None:
            out = out @ turn.T  # back to the world (``state.from_heading_frame``)
        return out

    def predict_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """``numpy_candidates`` with the shapes checked (``check_arrays``)."""
        check_arrays(x_hist, u_past, plans, self.history)
        return self.numpy_candidates(x_hist, u_past, plans)

    def prepare(self, m: int, k: int, n: int) -> None:
        """Compile and make the work arrays before the first control step (``warm_up``; the
        MPC calls it when built)."""
        warm_up(self, self.history, k, n, self.folded.vehicle)

    # --- the pieces ---------------------------------------------------------------------------

    def _work_for(self, shared: int, k: int) -> _Work:
        """The work arrays for ``shared`` = M - 1 history rows and K candidates, kept while
        the call's shapes stay."""
        if self._work is None or (self._work.shared, self._work.k) != (shared, k):
            self._work = _Work(self.folded, shared, k)
        return self._work

    def _load_state(self, x_rel: np.ndarray, aux: np.ndarray, vehicle: VehicleConstants) -> None:
        """The physics-step network's a_{M-1} (shared by the candidates) into aux (6, K), with
        f's constants ``vehicle``."""
        w = self.folded
        if w.mode != PHYSICS_STEP:
            return
        one = np.zeros(AUX_DIM, np.float64)
        m = x_rel.shape[0]
        if w.load_filters.shape[0] > 0:
            if m < 3:
                raise ValueError(
                    f"the smoothed load estimate needs M >= 3 history steps; got M = {m}"
                )
            fit_load_state(x_rel, m, w.load_filters, vehicle, one)
        else:
            estimate_load_state(x_rel[-2], x_rel[-1], vehicle, one)
        aux[:] = one[:, None]

    def _embed(self, cols: np.ndarray, outs: list[np.ndarray], bias0: np.ndarray) -> np.ndarray:
        """The input embedding of columns (17, R) into ``outs`` (one array per layer, (E_i,
        R)), ``bias0`` the first layer's bias; returns the last."""
        h = cols
        for i, ((weight, bias), out) in enumerate(zip(self.folded.embed, outs, strict=True)):
            np.matmul(weight, h, out=out)
            bias_gelu(out, bias0 if i == 0 else bias)
            h = out
        return h

    def _encode(
        self, x_rel: np.ndarray, u_past: np.ndarray, b: _Work, bias0: np.ndarray
    ) -> np.ndarray:
        """The encoder: the M - 1 shared rows at batch 1, the last step at batch K (its input
        b.xu); leaves the decoder's starting state in b.h, b.c, the last embedding (the first
        decoder step's) in the last embedding rows, the candidates' last keys and context
        projections in b.keys_last, b.ctx_last. Returns layer 0's stacked weights for this call:
        [context (on the shared rows' outputs) | embedding | recurrent]."""
        w = self.folded
        layers, _, hidden = w.enc_hh.shape
        rows = np.ascontiguousarray(np.concatenate([x_rel[:-1], u_past], axis=1).T, np.float32)
        emb = self._embed(
            rows, [np.empty((wt.shape[0], rows.shape[1]), np.float32) for wt, _ in w.embed], bias0
        )  # fmt: skip  (E, M-1)
        pre = emb.T @ w.enc_emb.T + w.enc_b[0]  # (M-1, 4H)
        h1 = np.zeros((layers, hidden), np.float32)
        c1 = np.zeros((layers, hidden), np.float32)
        enc = np.empty((rows.shape[1], hidden), np.float32)  # top layer's outputs
        encode_rows(np.ascontiguousarray(pre), *self._encoder_rows, h1, c1, enc)

        e = self._embed(b.xu, b.embed, bias0)
        for i in range(layers):  # the last step: shared state, each candidate's input
            base = w.enc_hh[i] @ h1[i] + w.enc_b[i]  # (4H,) the shared rows' share
            np.matmul(w.enc_emb if i == 0 else w.enc_ih[i], e if i == 0 else b.h[i - 1],
                      out=b.gates)  # fmt: skip
            b.c[i] = c1[i][:, None]
            lstm_cols_bias(b.gates, base, b.c[i], b.h[i])
        np.matmul(w.att_w, b.h[layers - 1], out=b.keys_last)
        np.matmul(w.dec_ctx, b.h[layers - 1], out=b.ctx_last)
        self._keys = np.ascontiguousarray(w.att_w @ enc.T)  # (H, M-1)
        ctx = w.dec_ctx @ enc.T  # (4H, M-1)
        return np.ascontiguousarray(np.concatenate([ctx, w.dec_emb, w.dec_hh[0]], 1))

    def _decoder_step(self, b: _Work, layer0: np.ndarray) -> None:
        """Attention and the stacked LSTM cell for one step of the K candidates (the last
        embedding rows hold this step's embedding): b.h and b.c advance in place."""
        w = self.folded
        layers = w.dec_hh.shape[0]
        np.matmul(w.att_u, b.h[layers - 1], out=b.query)
        attention_cols(
            b.query, w.att_v, self._keys, b.keys_last, b.ctx_last, w.dec_b[0], b.weights,
            b.ctx_part,
        )  # fmt: skip
        np.matmul(layer0, b.rows[: layer0.shape[1]], out=b.gates)
        lstm_cols_add(b.gates, b.ctx_part, b.c[0], b.h[0])
        for i in range(1, layers):
            np.matmul(self._upper[i - 1], b.pairs[i - 1], out=b.gates)
            lstm_cols_bias(b.gates, w.dec_b[i], b.c[i], b.h[i])

    def _head(self, b: _Work) -> None:
        """The head on the top hidden state into b.head; the last layer's bias is added by
        ``_next_columns``."""
        h = b.h[-1]
        head = self.folded.head
        for i, ((weight, bias), out) in enumerate(zip(head, b.head, strict=True)):
            np.matmul(weight, h, out=out)
            if i < len(head) - 1:
                bias_gelu(out, bias)
            h = out


@jit
def _next_columns(xu, y, y_bias, aux, mode, add_mean, vehicle, u_next, origin, out, step):
    """The decoder's state update for K candidates (columns), and their output rows.

    xu (17, K): (x_k relative to the origin, u_k), float32; y (13, K) + y_bias (13,) the head's
    state rows (the residual gain folded in); aux (6, K) the load state (physics step). mode
    (``weights``): RESIDUAL x + y, ABSOLUTE y + add_mean, PHYSICS_STEP f(x, u, aux) + y
    (``vehicle`` its constants). Then xu's state rows hold x_{k+1}, its input rows u_next (4,
    K) (when it has columns), and out[:, step] (K, N, 13) x_{k+1} + origin with a unit
    quaternion, float64.
    """
    k = xu.shape[1]
    if mode == PHYSICS_STEP:
        x_next, aux_next = np.empty((STATE_DIM, k)), np.empty((AUX_DIM, k))
        physics_step_columns(xu, aux, vehicle, np.empty((4, k)), x_next, aux_next)
        for j in range(AUX_DIM):
            aux[j] = aux_next[j]
        for j in range(STATE_DIM):
            xu[j] = x_next[j]
    for j in range(STATE_DIM):
        row, yj, bj = xu[j], y[j], y_bias[j]
        for r in range(k):
            v = yj[r] + bj
            row[r] = v + add_mean[j] if mode == ABSOLUTE else row[r] + v
    if u_next.shape[1] > 0:
        xu[STATE_DIM:] = u_next
    for r in range(k):
        qw, qx = float(xu[_Q, r]), float(xu[_Q + 1, r])
        qy, qz = float(xu[_Q + 2, r]), float(xu[_Q + 3, r])
        norm = max(math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz), 1e-12)
        for j in range(STATE_DIM):
            out[r, step, j] = xu[j, r] + origin[j]
        for j in range(4):
            out[r, step, _Q + j] = xu[_Q + j, r] / norm
