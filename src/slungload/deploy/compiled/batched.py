"""Fast batched rollouts for a sampling controller: ``PredictionModel``s on compiled kernels.

    model = load_model("runs/ps-exc", backend="compiled")   # deploy.backends; or "physics"
    states = model.predict_candidates(x_hist, u_past, plans)  # (K, N, 13), as the eager model

What a model-predictive controller asks for at every step is one history and K candidate
input sequences (``models.prediction``, ``predict_candidates``). The eager paths answer it with
torch operators: the network's decoder is ~60 of them per horizon step, the physics model's
step ~50 float64 ones, and at K = 256-4096 their element-wise work (attention tanh over K x M x
H, GELUs, gates, quaternions) and allocations cost as much as the matrix products. Here:

- ``CompiledPhysicsModel``: the discrete model rolled out for the K candidates in one compiled
  call (``physics.physics_rollout``: the compiled copy of ``physics.step`` over candidates in
  columns, per step), float64 as ``PhysicsModel``.
- ``CompiledNetworkModel``: the network's candidates in float32 on the weights of the one fold
  (``fold``: standardisation folded into the first layer, physical units relative to the last
  position, the head's Linears joined, the residual gain in the last layer), the batch-1
  predictor's. The matrix products go to torch's BLAS with preallocated outputs, everything
  between them to one ``kernels`` call each. As in the eager ``forward_candidates`` the encoder
  runs once over the M - 1 shared rows (batch 1) and only its last step at batch K; the
  attention works on the shared rows' keys and context projections once (no K copies of the
  encoder outputs); the last encoder step's embedding is the first decoder step's.

Both equal the eager model to float32 rounding for the network (tests: both architectures,
every model mode) and to round-off for the physics (float64); ``predict_windows`` is the eager
model's. The ``cuda`` backend is the eager model on the GPU, replayed from CUDA graphs
(``deploy.gpu``; CPU tensors in and out, as the MPC calls it). ``with_backend`` puts a model
on one of ``config.PREDICTION_BACKENDS`` (``deploy.backends.load_model`` loads and puts); a
model a backend cannot run, or a GPU that torch does not see, is a ``ValueError`` naming why,
never a silent fallback. Both compiled models also take the MPC's numpy call directly
(``numpy_candidates``, ``control.mppi.CandidateModel``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from ...config import PREDICTION_BACKENDS, VehicleParams
from ...constants_estimate import ADAPT_PRIOR_WEIGHT
from ...data.windows import Windows
from ...layout import AUX_DIM, INPUT_DIM, POS, QUAT, STATE_DIM
from ...models.ensemble import EnsembleModel
from ...models.prediction import (
    PHYSICS,
    NetworkModel,
    PhysicsModel,
    PredictionModel,
    check_candidates,
)
from ...physics import VehicleConstants
from ...state import from_heading_frame, heading_turn, to_heading_frame
from ..gpu import CUDA, on_gpu
from .fold import ABSOLUTE, PHYSICS_STEP, FoldedWeights, first_bias, fold
from .kernels import attention_cols, encode_rows, gelu, jit, lstm_cols
from .physics import (
    estimate_load_state,
    fit_load_state,
    history_constants,
    physics_rollout,
    physics_step_columns,
)

_Q = QUAT.start


@dataclass
class CompiledPhysicsModel:
    """``PhysicsModel``'s candidates in one compiled float64 loop (same constants, same
    causal load-state estimate from the last two measured states)."""

    params: VehicleParams
    name: str = PHYSICS
    history: int = 2
    constants: str = "dataset"  # or "window" (``PhysicsModel``'s; "flight" predicts windows only)
    prior_weight: float = ADAPT_PRIOR_WEIGHT  # the in-flight estimate's mass prior ("window")

    def __post_init__(self) -> None:
        self._eager = PhysicsModel(self.params, self.name, self.history, constants=self.constants,
                                   prior_weight=self.prior_weight)  # fmt: skip
        self.history = self._eager.history
        self._vehicle = VehicleConstants.of(self.params)

    def predict_windows(self, windows: Windows) -> Tensor:
        return self._eager.predict_windows(windows)

    def predict_candidates(self, x_hist: Tensor, u_past: Tensor, plans: Tensor) -> Tensor:
        check_candidates(x_hist, u_past, plans)
        if self.constants not in ("dataset", "window"):
            self._eager.predict_candidates(x_hist, u_past, plans)  # its error
        out = self.numpy_candidates(*_arrays(x_hist, u_past, plans))
        return torch.from_numpy(out).to(plans.device, plans.dtype)

    def numpy_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """``predict_candidates`` on float64 arrays, without torch: the MPC's call
        (``control.mppi.CandidateModel``, through ``control.mpc.candidate_model``)."""
        vehicle = self._vehicle
        if self.constants == "window":
            vehicle = history_constants(x_hist, u_past, vehicle, self.prior_weight)
        elif self.constants != "dataset":
            raise ValueError(
                f"the compiled physics predicts candidates with constants 'dataset' or "
                f"'window', not {self.constants!r}"
            )
        x = np.ascontiguousarray(x_hist[-2:], np.float64)
        aux = np.empty(AUX_DIM, np.float64)
        estimate_load_state(x[0], x[1], vehicle, aux)
        u = np.ascontiguousarray(plans, np.float64)
        out = np.empty((*u.shape[:2], STATE_DIM), np.float64)
        physics_rollout(x[1], aux, u, vehicle, out)
        return out


def _arrays(x_hist: Tensor, u_past: Tensor, plans: Tensor) -> tuple[np.ndarray, ...]:
    """A torch caller's candidates call as the float64 arrays of ``numpy_candidates`` (exact:
    float32 inputs widen without rounding)."""
    return tuple(t.detach().to("cpu", torch.float64).numpy() for t in (x_hist, u_past, plans))


class _Buffers:
    """Float32 work arrays for K candidates in columns (numpy ``a``, torch views ``t``)."""

    def __init__(self, k: int) -> None:
        self.k = k
        self.a: dict[str, np.ndarray] = {}
        self.t: dict[str, Tensor] = {}

    def add(self, name: str, *shape: int) -> None:
        self.a[name] = array = np.zeros(shape, np.float32)
        self.t[name] = torch.from_numpy(array)


class CompiledNetworkModel:
    """A network's candidates on compiled kernels and torch's BLAS, float32 (see the module).

    net: a ``SlungLoadNet`` or ``PhysicsStepNet`` (``fold.COMPILED_ARCHITECTURES``, any widths
    and layer counts; another architecture is a ``ValueError`` naming it); history: its M.
    ``predict_windows`` is ``NetworkModel``'s.

    The K candidates are the columns of every work array (features x K), so that each kernel's
    inner loop runs over the candidates and each product is W (out, in) @ X (in, K).
    """

    def __init__(self, net: torch.nn.Module, history: int, name: str = "network") -> None:
        self.folded = folded = fold(net)  # raises, naming why, for what it cannot run
        self.w = _columns(folded)
        self.constants = folded.constants
        self.name, self.history = name, history
        self._eager = NetworkModel(net, history, name=name)
        self._buffers: _Buffers | None = None
        # The encoder's batch-1 pass takes (in, out) matrices and (L, 4H) biases.
        rows = lambda a: np.ascontiguousarray(a.transpose(0, 2, 1))  # noqa: E731
        self._encoder_rows = (rows(folded.enc_ih), rows(folded.enc_hh), folded.enc_b)
        self._bias0 = folded.dec_b[0]

    def predict_windows(self, windows: Windows) -> Tensor:
        return self._eager.predict_windows(windows)

    def predict_candidates(self, x_hist: Tensor, u_past: Tensor, plans: Tensor) -> Tensor:
        check_candidates(x_hist, u_past, plans)
        out = self.numpy_candidates(*_arrays(x_hist, u_past, plans))
        return torch.from_numpy(out).to(plans.device, plans.dtype)

    def numpy_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """``predict_candidates`` on float64 arrays (K, N, 13) out: the MPC's call
        (``control.mppi.CandidateModel``, through ``control.mpc.candidate_model``), no tensor
        conversion at its edges."""
        w = self.w
        x = np.asarray(x_hist, np.float64)
        twist = self._eager.net.heading(torch.from_numpy(x[-1]))  # the network's frame undoes it
        turn = None if twist is None else heading_turn(twist)
        if turn is not None:
            x = to_heading_frame(torch.from_numpy(x), turn).numpy()
        origin = x[-1, POS] @ w.origin_shift  # (13,)
        x_rel = x - origin
        u_cols = np.ascontiguousarray(np.asarray(plans).transpose(1, 2, 0), np.float32)  # (N, 4, K)
        n, _, k = u_cols.shape
        b = self._buffers_for(k)
        vehicle, embed = w.vehicle, w.embed
        if self.constants == "window":  # the history's own, and the embedding's bias with them
            vehicle = history_constants(x_rel, u_past, w.vehicle)
            bias0 = torch.from_numpy(first_bias(self.folded, vehicle))[:, None]
            embed = [(embed[0][0], bias0), *embed[1:]]
        aux = self._load_state(x_rel, b.a["aux"], vehicle)
        b.a["xu"][:STATE_DIM] = x_rel[-1, :, None]
        b.a["xu"][STATE_DIM:] = u_cols[0]
        shared = self._encode(x_rel, np.asarray(u_past), b, embed)
        out = np.empty((k, n, STATE_DIM), np.float64)
        no_input = np.empty((INPUT_DIM, 0), np.float32)
        for step in range(n):
            if step > 0:  # step 0's embedding is the last encoder step's
                self._embed(b.t["xu"], b, embed)
            self._decoder_step(b, shared)
            u_next = u_cols[step + 1] if step + 1 < n else no_input
            _next_columns(
                b.a["xu"], self._head(b), aux, w.mode, w.add_mean, vehicle, u_next, origin,
                out, step,
            )  # fmt: skip
        if turn is not None:
            out = from_heading_frame(torch.from_numpy(out), turn).numpy()
        return out

    # --- the pieces ---------------------------------------------------------------------------

    def _buffers_for(self, k: int) -> _Buffers:
        if self._buffers is not None and self._buffers.k == k:
            return self._buffers
        w, b = self.w, _Buffers(k)
        layers, gates, hidden = w.dec_hh.shape
        b.add("xu", STATE_DIM + INPUT_DIM, k)
        for i, (weight, _) in enumerate(w.embed):
            b.add(f"e{i}", weight.shape[0], k)
        for i, (weight, _) in enumerate(w.head):
            b.add(f"y{i}", weight.shape[0], k)
        for name, rows in (("gates", gates), ("query", hidden), ("keys_last", hidden)):
            b.add(name, rows, k)
        b.add("ctx_last", gates, k)
        b.add("h", layers, hidden, k)
        b.add("c", layers, hidden, k)
        b.add("aux", AUX_DIM, k)
        self._buffers = b
        return b

    def _load_state(
        self, x_rel: np.ndarray, aux: np.ndarray, vehicle: VehicleConstants
    ) -> np.ndarray:
        """The physics-step network's a_{M-1} (shared by the candidates) into aux (6, K), with
        f's constants ``vehicle``."""
        w = self.w
        if w.mode != PHYSICS_STEP:
            return aux
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
        return aux

    def _embed(
        self, cols: Tensor, b: _Buffers | None, embed: list[tuple[Tensor, Tensor]]
    ) -> Tensor:
        """The input embedding (layers ``embed``: this call's) of columns (17, R) into b's
        buffers (new arrays when b is None); returns the last layer's output (E, R)."""
        h = cols
        for i, (weight, bias) in enumerate(embed):
            if b is None:
                h = torch.addmm(bias, weight, h)
            else:
                h = torch.addmm(bias, weight, h, out=b.t[f"e{i}"])
            gelu(h.numpy())
        return h

    def _encode(
        self, x_rel: np.ndarray, u_past: np.ndarray, b: _Buffers, embed: list[tuple[Tensor, Tensor]]
    ) -> dict:
        """The encoder: the M - 1 shared rows at batch 1, the last step at batch K (its input
        b.xu); leaves the decoder's starting state in b.h, b.c, the last embedding (the first
        decoder step's) in the last e buffer, the candidates' last keys and context
        projections in b.keys_last, b.ctx_last. Returns what the attention shares."""
        w, t = self.w, torch.from_numpy
        layers, _, hidden = w.enc_hh.shape
        rows = np.concatenate([x_rel[:-1], u_past], axis=1).astype(np.float32).T  # (17, M-1)
        emb = self._embed(t(np.ascontiguousarray(rows)), None, embed)  # (E, M-1)
        pre = torch.addmm(w.enc_b[0].t(), emb.t(), w.enc_emb.t()).numpy()  # (M-1, 4H)
        h1 = np.zeros((layers, hidden), np.float32)
        c1 = np.zeros((layers, hidden), np.float32)
        enc = np.empty((rows.shape[1], hidden), np.float32)  # top layer's outputs
        encode_rows(pre, *self._encoder_rows, h1, c1, enc)

        gates, h, c = b.t["gates"], b.t["h"], b.t["c"]
        e = self._embed(b.t["xu"], b, embed)
        for i in range(layers):  # the last step: shared state, each candidate's input
            base = torch.addmm(w.enc_b[i], w.enc_hh[i], t(h1[i][:, None]))  # (4H, 1)
            w_in, x_in = (w.enc_emb, e) if i == 0 else (w.enc_ih[i], h[i - 1])
            torch.addmm(base, w_in, x_in, out=gates)
            c[i] = t(c1[i][:, None])
            lstm_cols(b.a["gates"], b.a["c"][i], b.a["h"][i])
        torch.mm(w.att_w, h[layers - 1], out=b.t["keys_last"])
        torch.mm(w.dec_ctx, h[layers - 1], out=b.t["ctx_last"])
        enc_cols = t(np.ascontiguousarray(enc.T))  # (H, M-1)
        weights = np.empty((enc.shape[0], b.k), np.float32)  # softmax over the shared rows
        return {
            "keys": (w.att_w @ enc_cols).numpy(),  # (H, M-1)
            "ctx": w.dec_ctx @ enc_cols,  # (4H, M-1)
            "weights": weights,
            "weights_t": t(weights),
        }

    def _decoder_step(self, b: _Buffers, shared: dict) -> None:
        """Attention and the stacked LSTM cell for one step of the K candidates (the last e
        buffer holds this step's embedding): b.h and b.c advance in place."""
        w = self.w
        layers = w.dec_hh.shape[0]
        h, c, gates = b.a["h"], b.a["c"], b.a["gates"]
        tg, th = b.t["gates"], b.t["h"]
        torch.mm(w.att_u, th[layers - 1], out=b.t["query"])
        attention_cols(
            b.a["query"], w.att_v, shared["keys"], b.a["keys_last"], b.a["ctx_last"],
            self._bias0, shared["weights"], gates,
        )  # fmt: skip
        tg.addmm_(shared["ctx"], shared["weights_t"])
        tg.addmm_(w.dec_emb, b.t[f"e{len(w.embed) - 1}"])
        tg.addmm_(w.dec_hh[0], th[0])
        lstm_cols(gates, c[0], h[0])
        for i in range(1, layers):
            torch.addmm(w.dec_b[i], w.dec_ih[i], th[i - 1], out=tg)
            tg.addmm_(w.dec_hh[i], th[i])
            lstm_cols(gates, c[i], h[i])

    def _head(self, b: _Buffers) -> np.ndarray:
        """The head on the top hidden state: the state rows (13, K), residual gain folded."""
        h = b.t["h"][-1]
        head = self.w.head
        for i, (weight, bias) in enumerate(head):
            h = torch.addmm(bias, weight, h, out=b.t[f"y{i}"])
            if i < len(head) - 1:
                gelu(b.a[f"y{i}"])
        return b.a[f"y{len(head) - 1}"]


class _Columns(NamedTuple):
    """``FoldedWeights`` as ``CompiledNetworkModel``'s products take them: matrices (out, in)
    and biases (out, 1) as float32 torch tensors sharing the folded arrays' memory; the
    kernels' vectors as numpy."""

    embed: list[tuple[Tensor, Tensor]]  # GELU after each
    head: list[tuple[Tensor, Tensor]]  # GELU after each but the last; the last (13, .)
    enc_emb: Tensor  # (G, E)
    enc_ih: Tensor  # (L, G, H)
    enc_hh: Tensor  # (L, G, H)
    enc_b: Tensor  # (L, G, 1)
    att_w: Tensor  # (H, H)
    att_u: Tensor  # (H, H)
    att_v: np.ndarray  # (H,)
    dec_ctx: Tensor  # (G, H)
    dec_emb: Tensor  # (G, E)
    dec_ih: Tensor  # (L, G, H)
    dec_hh: Tensor  # (L, G, H)
    dec_b: Tensor  # (L, G, 1)
    add_mean: np.ndarray  # (13,)
    mode: int  # ``fold.RESIDUAL``, ``ABSOLUTE`` or ``PHYSICS_STEP``
    origin_shift: np.ndarray  # (3, 13)
    vehicle: VehicleConstants
    load_filters: np.ndarray


def _columns(w: FoldedWeights) -> _Columns:
    t = torch.from_numpy
    return _Columns(
        embed=[(t(weight), t(bias)[:, None]) for weight, bias in w.embed],
        head=[(t(weight), t(bias)[:, None]) for weight, bias in w.head],
        enc_emb=t(w.enc_emb), enc_ih=t(w.enc_ih), enc_hh=t(w.enc_hh), enc_b=t(w.enc_b)[..., None],
        att_w=t(w.att_w), att_u=t(w.att_u), att_v=w.att_v,
        dec_ctx=t(w.dec_ctx), dec_emb=t(w.dec_emb), dec_ih=t(w.dec_ih), dec_hh=t(w.dec_hh),
        dec_b=t(w.dec_b)[..., None],
        add_mean=w.add_mean, mode=w.mode, origin_shift=w.origin_shift, vehicle=w.vehicle,
        load_filters=w.load_filters,
    )  # fmt: skip


@jit
def _next_columns(xu, y, aux, mode, add_mean, vehicle, u_next, origin, out, step):
    """The decoder's state update for K candidates (columns), and their output rows.

    xu (17, K): (x_k relative to the origin, u_k), float32; y (13, K) the head's state rows
    (the residual gain folded in); aux (6, K) the load state (physics step). mode (``fold``):
    RESIDUAL x + y, ABSOLUTE y + add_mean, PHYSICS_STEP f(x, u, aux) + y (``vehicle`` its
    constants). Then xu's state rows hold x_{k+1}, its input rows u_next (4, K) (when it has
    columns), and out[:, step] (K, N, 13) x_{k+1} + origin with a unit quaternion, float64.
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
        row, yj = xu[j], y[j]
        for r in range(k):
            row[r] = yj[r] + add_mean[j] if mode == ABSOLUTE else row[r] + yj[r]
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


def with_backend(model: PredictionModel, backend: str) -> PredictionModel:
    """``model`` on ``backend`` (one of ``config.PREDICTION_BACKENDS``): itself for "eager";
    for "compiled" a ``CompiledPhysicsModel`` of a ``PhysicsModel`` or a
    ``CompiledNetworkModel`` of a ``NetworkModel`` on the CPU; for "cuda" a
    ``deploy.gpu.GraphedModel`` of a copy on the GPU; an ``EnsembleModel`` with each member so.
    Anything else is a ``ValueError`` naming why, a GPU that torch does not see too."""
    if backend not in PREDICTION_BACKENDS:
        raise ValueError(
            f"unknown prediction backend {backend!r}; known: {list(PREDICTION_BACKENDS)}"
        )
    if backend == "eager":
        return model
    if isinstance(model, EnsembleModel):  # each member on the backend, the mean taken outside
        return model.with_members(tuple(with_backend(m, backend) for m in model.members))
    if backend == CUDA:
        return on_gpu(model)
    if isinstance(model, PhysicsModel):
        return CompiledPhysicsModel(
            model.params, model.name, model.history, model.constants, model.prior_weight
        )
    if isinstance(model, NetworkModel):
        if torch.device(model.device).type != "cpu":
            raise ValueError(
                f"the compiled backend runs on the CPU; {model.name!r} is on {model.device}"
            )
        return CompiledNetworkModel(model.net, model.history, model.name)
    raise ValueError(
        f"the compiled backend runs a PhysicsModel or a NetworkModel, not a {type(model).__name__}"
    )
