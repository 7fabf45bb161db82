"""The network: LSTM encoder-decoder with Bahdanau attention (the paper's Section III-B).

Read top to bottom: input embedding, encoder, attention, decoder head, the network with its
recursive decoder loop. Shapes use B batch, M history steps, N horizon steps, E = 300 the
embedding width, H = 20 the LSTM width.

The network takes and returns **physical units** (m, m/s, unit-ish quaternion w-x-y-z, m;
N, rad/s). With ``ModelConfig.normalize`` it standardises internally with statistics stored in
buffers (``fit_normalization``), so they travel with the ``state_dict`` and any export.

Recursion (no teacher forcing)::

    step 0:  (x_{M-1},        u_{M-1})   -> x_hat_M
    step n:  (x_hat_{M-1+n},  u_{M-1+n}) -> x_hat_{M+n}

so predicting N states uses the inputs u_{M-1} ... u_{M+N-2}. ``forward`` takes the inputs over
the horizon u_M ... u_{M+N-1} (as the data windows hold them) and does not use the last one.
"""

from __future__ import annotations

from itertools import pairwise
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..config import CONDITIONED, DEFAULT_ARCHITECTURE, ModelConfig, VehicleParams
from ..state import (
    INPUT_DIM,
    LOAD_POS,
    POS,
    QUAT,
    STATE_DIM,
    from_heading_frame,
    heading_turn,
    heading_twist,
    to_heading_frame,
)
from .base import Prediction

FEATURE_DIM = STATE_DIM + INPUT_DIM  # 17: one (x_k, u_k) pair

# Floors on the standard deviations from ``fit_normalization``: a (near-)constant channel
# must not turn into a huge gain. Quaternion components live in [-1, 1]; a much tighter
# floor would make a flight at near-constant attitude hypersensitive to tiny attitude changes.
STD_FLOOR = 1e-3  # state (m, m/s) and input (N, rad/s) channels
QUAT_STD_FLOOR = 0.05  # quaternion channels, -
DELTA_STD_FLOOR = 1e-5  # per-step changes x_k - x_{k-1}, same units as the state


class InputEmbedding(nn.Module):
    """(x_k, u_k[, c]) (..., 17 + C) -> z_k (..., E): Linear -> GELU, repeated, dropout between.

    Shared by the encoder and the decoder. c: ``extra`` per-window columns after the input's
    (C = 0 unless the network sees its constants, ``ModelConfig.constants_input``). The first
    Linear is split in its state columns and the rest so the decoder can apply the rest to the
    whole horizon at once (``input_part``) and only the state part inside its loop
    (``from_parts``).
    """

    def __init__(self, sizes: tuple[int, ...], dropout: float, extra: int = 0) -> None:
        super().__init__()
        widths = (FEATURE_DIM + extra, *sizes)
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in pairwise(widths))
        self.dropout = nn.Dropout(dropout)

    def forward(self, features: Tensor) -> Tensor:  # (..., 17) -> (..., E)
        return self._rest(self.layers[0](features))

    def input_part(self, u: Tensor) -> Tensor:
        """First layer's input (and extra) columns plus bias: (..., 4 + C) -> (..., sizes[0])."""
        first = self.layers[0]
        return F.linear(u, first.weight[:, STATE_DIM:], first.bias)

    def state_weight(self) -> Tensor:
        """First layer's state columns, transposed: (13, sizes[0]), for ``from_parts``."""
        return self.layers[0].weight[:, :STATE_DIM].t()

    def from_parts(self, x: Tensor, input_part: Tensor, state_weight: Tensor) -> Tensor:
        """Embedding of (x, u) given ``input_part(u)`` and ``state_weight()``.

        x (B, 13), input_part (B, sizes[0]), state_weight (13, sizes[0]) -> (B, E).
        """
        return self._rest(torch.addmm(input_part, x, state_weight))

    def _rest(self, h: Tensor) -> Tensor:
        h = F.gelu(h)
        for layer in self.layers[1:]:
            h = F.gelu(layer(self.dropout(h)))
        return h


class BahdanauAttention(nn.Module):
    """Additive attention: score_j = v^T tanh(W enc_j + U h), softmax over the M history steps."""

    def __init__(self, hidden: int) -> None:
        super().__init__()
        self.W = nn.Linear(hidden, hidden, bias=False)
        self.U = nn.Linear(hidden, hidden, bias=False)
        self.v = nn.Linear(hidden, 1, bias=False)

    def keys(self, enc: Tensor) -> Tensor:
        """W enc, (B, M, H): depends only on the encoder, so computed once per sequence."""
        return self.W(enc)

    def forward(self, keys: Tensor, enc: Tensor, query: Tensor) -> Tensor:
        """Context (B, H) from keys = W enc (B, M, H), enc (B, M, H), query h (B, H)."""
        scores = self.v(torch.tanh(keys + self.U(query).unsqueeze(1)))  # (B, M, 1)
        weights = torch.softmax(scores, dim=1)  # (B, M, 1)
        return (weights * enc).sum(dim=1)  # (B, H)


class OutputHead(nn.Module):
    """Decoder output (B, H) -> (B, 13 [+ 13 slack]).

    Linear -> Linear -> GELU -> Linear -> GELU -> Linear: the first two Linears have no
    activation between them (this is what gives the paper's parameter count). Their product is
    one (sizes[1], H) matrix, so ``joined`` multiplies them once per sequence and ``apply``
    runs the decoder's steps through it: the same function with ~15x fewer multiply-adds in
    that layer; gradients reach both Linears through the product.
    """

    def __init__(self, hidden: int, sizes: tuple[int, ...], out: int) -> None:
        super().__init__()
        widths = (hidden, *sizes, out)
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in pairwise(widths))

    def forward(self, h: Tensor) -> Tensor:
        return self.apply_joined(h, self.joined())

    def joined(self) -> list[tuple[Tensor, Tensor]]:
        """(weight, bias) per layer after the first two are multiplied (when there are more
        than two layers; a head of one or two Linears is returned as it is)."""
        pairs = [(layer.weight, layer.bias) for layer in self.layers]
        if len(pairs) > 2:
            (w0, b0), (w1, b1) = pairs[:2]
            pairs[:2] = [(w1 @ w0, w1 @ b0 + b1)]
        return pairs

    def apply_joined(self, h: Tensor, joined: list[tuple[Tensor, Tensor]]) -> Tensor:
        """The head on h (B, H) with weights from ``joined``."""
        if len(self.layers) == 2:  # Linear -> Linear without an activation
            return F.linear(F.linear(h, *joined[0]), *joined[1])
        for weight, bias in joined[:-1]:
            h = F.gelu(F.linear(h, weight, bias))
        return F.linear(h, *joined[-1])


class SlungLoadNet(nn.Module):
    """Encoder-decoder that predicts N future states from M past states and inputs.

    ``self.decoder`` is an ``nn.LSTM`` so the parameters have the standard layout and count,
    but the loop runs its step by hand (``_lstm_cell``): at batch 1 the per-call overhead of
    ``nn.LSTM`` is several times the arithmetic.

    An architecture built on this one (same layers, same parameters) changes how each decoder
    step turns the head's output into the next state by overriding ``start_rollout`` and
    ``next_state`` (e.g. ``physics_step.PhysicsStepNet``).
    """

    architecture = DEFAULT_ARCHITECTURE  # its name in ``models.MODELS``

    def __init__(
        self, config: ModelConfig | None = None, params: VehicleParams | None = None
    ) -> None:
        """``params`` (the vehicle constants) is part of every architecture's signature; the
        paper's network does not use them."""
        super().__init__()
        cfg = config or ModelConfig(architecture=self.architecture)
        if cfg.architecture != self.architecture:
            raise ValueError(
                f"{type(self).__name__} is the {self.architecture!r} architecture; the config "
                f"names {cfg.architecture!r} (build it with models.build)"
            )
        self.config = cfg
        hidden, layers = cfg.hidden_size, cfg.num_layers
        embed = cfg.embed_sizes[-1]
        extra = len(CONDITIONED) if cfg.constants_input else 0
        self.embed = InputEmbedding(cfg.embed_sizes, cfg.dropout, extra)
        between = cfg.dropout if layers > 1 else 0.0  # nn.LSTM drops out between its layers
        self.encoder = nn.LSTM(embed, hidden, layers, dropout=between, batch_first=True)
        self.attention = BahdanauAttention(hidden)
        self.decoder = nn.LSTM(hidden + embed, hidden, layers, dropout=between, batch_first=True)
        self.head = OutputHead(hidden, cfg.head_sizes, STATE_DIM * (2 if cfg.slack else 1))
        # Normalisation statistics, physical units; identity until ``fit_normalization``.
        self.register_buffer("state_mean", torch.zeros(STATE_DIM))
        self.register_buffer("state_std", torch.ones(STATE_DIM))
        self.register_buffer("input_mean", torch.zeros(INPUT_DIM))
        self.register_buffer("input_std", torch.ones(INPUT_DIM))
        self.register_buffer("delta_std", torch.ones(STATE_DIM))
        # (3, 13) selector: a vehicle position p -> the state offset that moves p and pL by p.
        shift = torch.zeros(3, STATE_DIM)
        if cfg.relative_positions:
            shift[:, POS] = torch.eye(3)
            shift[:, LOAD_POS] = torch.eye(3)
        self.register_buffer("position_shift", shift, persistent=False)

    # --- normalisation -------------------------------------------------------------------

    def origin(self, x_last: Tensor) -> Tensor:
        """State offset (..., 13) that ``forward`` subtracts from positions: the vehicle
        position of x_last (..., 13) in the p and pL slots, zero elsewhere (all zero when
        ``ModelConfig.relative_positions`` is off)."""
        return x_last[..., POS] @ self.position_shift

    @torch.no_grad()
    def fit_normalization(self, states: Tensor, inputs: Tensor, *, origin_step: int = -1) -> None:
        """Set the normalisation buffers from training data.

        states (..., T, 13) and inputs (..., T, 4), e.g. windows (W, T, .) or one flight
        (T, .); physical units. Per-channel mean and standard deviation (floored, see
        ``STD_FLOOR``), and the standard deviation of the per-step change x_k - x_{k-1}
        (used by the residual mode and to scale the slack variables). With relative
        positions, each sequence is first shifted by ``origin`` of its step ``origin_step``
        (pass M - 1 for windows: the step ``forward`` uses).
        """
        if not self.config.normalize:
            raise ValueError("fit_normalization: this model was built with normalize=False")
        if states.shape[-1] != STATE_DIM or inputs.shape[-1] != INPUT_DIM:
            raise ValueError(
                f"fit_normalization: expected states (..., T, {STATE_DIM}) and inputs "
                f"(..., T, {INPUT_DIM}), got {tuple(states.shape)} and {tuple(inputs.shape)}"
            )
        if states.shape[-2] < 2:
            raise ValueError("fit_normalization: need at least 2 time steps for delta_std")
        x = states.detach().to(torch.float64)
        twist = self.heading(x[..., origin_step, :])
        if twist is not None:  # the statistics of what the network sees
            x = to_heading_frame(x, heading_turn(twist))
        x = x - (x[..., origin_step, POS] @ self.position_shift.double()).unsqueeze(-2)
        u = inputs.detach().to(torch.float64)
        flat_x, flat_u = x.reshape(-1, STATE_DIM), u.reshape(-1, INPUT_DIM)
        delta = (x[..., 1:, :] - x[..., :-1, :]).reshape(-1, STATE_DIM)
        floor = torch.full((STATE_DIM,), STD_FLOOR, dtype=torch.float64)
        floor[QUAT] = QUAT_STD_FLOOR
        self._set("state_mean", flat_x.mean(0))
        self._set("state_std", flat_x.std(0, correction=0).maximum(floor))
        self._set("input_mean", flat_u.mean(0))
        self._set("input_std", flat_u.std(0, correction=0).clamp_min(STD_FLOOR))
        self._set("delta_std", delta.std(0, correction=0).clamp_min(DELTA_STD_FLOOR))

    def _set(self, name: str, value: Tensor) -> None:
        buf = getattr(self, name)
        buf.copy_(value.to(buf.dtype))

    def normalize_state(self, x: Tensor) -> Tensor:
        """Physical (..., 13) -> network units (identity when normalize=False)."""
        if not self.config.normalize:
            return x
        return (x - self.state_mean) / self.state_std

    def denormalize_state(self, z: Tensor) -> Tensor:
        """Network units (..., 13) -> physical (identity when normalize=False)."""
        if not self.config.normalize:
            return z
        return z * self.state_std + self.state_mean

    def normalize_input(self, u: Tensor) -> Tensor:
        """Physical (..., 4) -> network units (identity when normalize=False)."""
        if not self.config.normalize:
            return u
        return (u - self.input_mean) / self.input_std

    # --- forward -------------------------------------------------------------------------

    def forward(self, x_hist: Tensor, u_hist: Tensor, u_future: Tensor) -> Prediction:
        """Predict x_M ... x_{M+N-1}.

        x_hist (B, M, 13) states x_0 ... x_{M-1}; u_hist (B, M, 4) inputs u_0 ... u_{M-1};
        u_future (B, N, 4) inputs u_M ... u_{M+N-1}; the horizon N is u_future.shape[1].
        The recursion uses u_{M-1} ... u_{M+N-2}; u_{M+N-1} does not affect the result.
        """
        _check_shapes(x_hist, u_hist, u_future)
        twist = self.heading(x_hist[:, -1])  # (B, 4) or None
        turn = None if twist is None else heading_turn(twist)  # (B, 13, 13)
        if turn is not None:
            x_hist = to_heading_frame(x_hist, turn)
        origin = self.origin(x_hist[:, -1]).unsqueeze(1)  # (B, 1, 13)
        x_rel = x_hist - origin  # (B, M, 13) positions relative to the origin
        z_hist = self.normalize_state(x_rel)  # (B, M, 13)
        carry = self.start_rollout(x_rel, u_hist, u_future)
        cond = self.conditioning(carry)  # (B, C) or None
        features = _with(torch.cat([z_hist, self.normalize_input(u_hist)], -1), cond)
        enc, state = self.encoder(self.embed(features))
        pred = self._decode(enc, state, x_rel, u_hist, u_future, origin, carry, cond)
        return self.world_frame(pred, twist, turn)

    def heading(self, x_last: Tensor) -> Tensor | None:
        """The heading (``state.heading_twist``, (..., 4)) of the states x_last (..., 13) that
        the network's frame undoes, or None unless ``ModelConfig.heading_frame``."""
        return heading_twist(x_last[..., QUAT]) if self.config.heading_frame else None

    def world_frame(
        self, pred: Prediction, twist: Tensor | None, turn: Tensor | None
    ) -> Prediction:
        """A prediction made in the heading frame of ``twist`` (``turn``: its ``heading_turn``)
        turned back (as it is for None): the states as states, the slack as the errors it is
        added to (``loss.physics_residual``)."""
        if twist is None or turn is None:
            return pred
        states = from_heading_frame(pred.states, turn)
        slack = pred.slack
        if slack is not None:
            slack = from_heading_frame(slack, heading_turn(twist, errors=True))
        return Prediction(states, slack)

    def forward_candidates(self, x_hist: Tensor, u_past: Tensor, plans: Tensor) -> Prediction:
        """K candidate futures from one history, as a model-predictive controller asks for.

        x_hist (M, 13) states x_0 ... x_{M-1}; u_past (M-1, 4) inputs u_0 ... u_{M-2};
        plans (K, N, 4) candidate inputs u_{M-1} ... u_{M+N-2}. Returns the K predictions of
        x_M ... x_{M+N-1}: the same as ``forward`` with the history repeated K times, the
        candidate's first row as the history's last input and its other rows (the last one
        repeated) as u_future, but the encoder runs once over the M-1 rows all candidates
        share and only its last step runs at batch K.
        """
        m, k = x_hist.shape[0], plans.shape[0]
        if m < 2 or u_past.shape[0] != m - 1:
            raise ValueError(
                f"forward_candidates: expected x_hist (M >= 2, 13) and u_past (M-1, 4); got "
                f"{tuple(x_hist.shape)} and {tuple(u_past.shape)}"
            )
        u_hist = torch.cat([u_past.expand(k, m - 1, INPUT_DIM), plans[:, :1]], dim=1)
        u_future = torch.cat([plans[:, 1:], plans[:, -1:]], dim=1)
        twist = self.heading(x_hist[-1])  # (4,) or None: the candidates share it
        turn = None if twist is None else heading_turn(twist)  # (13, 13)
        if turn is not None:
            x_hist = to_heading_frame(x_hist, turn)
        x_hist = x_hist.expand(k, m, STATE_DIM)  # views: one copy of the history
        _check_shapes(x_hist, u_hist, u_future)
        origin = self.origin(x_hist[:1, -1]).unsqueeze(1)  # (1, 1, 13), shared
        x_rel = x_hist - origin  # (K, M, 13)
        z_hist = self.normalize_state(x_rel[:1])  # (1, M, 13)
        carry = self.start_rollout(x_rel, u_hist, u_future)
        # (K, C) or None; the same for every candidate (they share the history)
        cond = self.conditioning(carry)
        shared = torch.cat([z_hist[:, :-1], self.normalize_input(u_past).unsqueeze(0)], -1)
        shared = _with(shared, None if cond is None else cond[:1])
        enc_shared, (h, c) = self.encoder(self.embed(shared))  # (1, M-1, H); (layers, 1, H)
        last = torch.cat(
            [z_hist[:, -1].expand(k, STATE_DIM), self.normalize_input(plans[:, 0])], -1
        )
        last = _with(last.unsqueeze(1), cond)
        state = (h.expand(-1, k, -1).contiguous(), c.expand(-1, k, -1).contiguous())
        enc_last, state = self.encoder(self.embed(last), state)  # (K, 1, H)
        enc = torch.cat([enc_shared.expand(k, -1, -1), enc_last], dim=1)  # (K, M, H)
        pred = self._decode(enc, state, x_rel, u_hist, u_future, origin, carry, cond)
        return self.world_frame(pred, twist, turn)

    def _decode(
        self,
        enc: Tensor,
        state: tuple[Tensor, Tensor],
        x_rel: Tensor,
        u_hist: Tensor,
        u_future: Tensor,
        origin: Tensor,
        carry: Any,
        cond: Tensor | None,
    ) -> Prediction:
        """The attention decoder's N steps from the encoder's outputs enc (B, M, H) and final
        state (h, c) (layers, B, H); x_rel (B, M, 13) the history relative to ``origin``
        (B or 1, 1, 13), inputs as ``forward`` takes them (physical units), ``carry`` from
        ``start_rollout``, ``cond`` (B, C) from ``conditioning``."""
        cfg = self.config
        h, c = state
        z_hist = self.normalize_state(x_rel[:, -1:])  # (B, 1, 13) the last measured state
        v_hist = self.normalize_input(u_hist[:, -1:])  # (B, 1, 4) its input
        v_future = self.normalize_input(u_future)  # (B, N, 4)
        keys = self.attention.keys(enc)  # (B, M, H)

        # Decoder inputs u_{M-1} ... u_{M+N-2}: their share of the first embedding layer is
        # computed for the whole horizon at once.
        v_dec = torch.cat([v_hist[:, -1:], v_future[:, :-1]], dim=1)  # (B, N, 4)
        input_parts = self.embed.input_part(_with(v_dec, cond)).unbind(1)  # N x (B, E0)

        state_weight = self.embed.state_weight()  # (13, E0)
        head = self.head.joined()
        weights = _stacked_lstm_weights(self.decoder)  # per layer (in + H, 4H), (4H,)
        hs, cs = list(h.unbind(0)), list(c.unbind(0))  # layers x (B, H)
        z = z_hist[:, -1]  # (B, 13) last measured state, network units
        states, slacks = [], []
        for k, part in enumerate(input_parts):
            context = self.attention(keys, enc, hs[-1])  # (B, H)
            emb = self.embed.from_parts(z, part, state_weight)  # (B, E)
            layer_in = torch.cat([context, emb], dim=-1)  # (B, H + E)
            for i, (w, b) in enumerate(weights):
                if i > 0:
                    layer_in = F.dropout(layer_in, cfg.dropout, self.training)
                hs[i], cs[i] = _lstm_cell(layer_in, hs[i], cs[i], w, b)
                layer_in = hs[i]
            y = self.head.apply_joined(layer_in, head)  # (B, 13 or 26)
            z, carry = self.next_state(z, y[:, :STATE_DIM], k, carry)
            states.append(z)
            if cfg.slack:
                slacks.append(y[:, STATE_DIM:])

        x_hat = self.denormalize_state(torch.stack(states, dim=1)) + origin  # (B, N, 13)
        slack = None
        if cfg.slack:
            slack = torch.stack(slacks, dim=1)  # (B, N, 13)
            if cfg.normalize:
                slack = slack * self.delta_std  # see ``Prediction``
        return Prediction(x_hat, slack)

    # --- the decoder's state update (the hook an architecture built on this one overrides) ---

    def start_rollout(self, x_rel: Tensor, u_hist: Tensor, u_future: Tensor) -> Any:
        """What ``next_state`` carries from one decoder step to the next, computed once per
        sequence before the loop: here the residual gain delta_std / state_std (13,), or None
        without normalisation.

        x_rel (B, M, 13) the history in physical units with positions relative to ``origin``;
        u_hist (B, M, 4), u_future (B, N, 4) as ``forward`` takes them (physical units).
        """
        # Residual mode: x_k = x_{k-1} + delta_std * out, written in network units.
        return self.delta_std / self.state_std if self.config.normalize else None

    def conditioning(self, carry: Any) -> Tensor | None:
        """The per-window columns (B, C) the embedding takes after each step's input (from
        ``start_rollout``'s carry), or None: the paper's network has none."""
        return None

    def next_state(self, z: Tensor, out: Tensor, k: int, carry: Any) -> tuple[Tensor, Any]:
        """Decoder step k's next state in network units: z_{M+k} (B, 13) from z_{M-1+k} (the
        last measured state for k = 0), the head's state rows ``out`` (B, 13) and ``carry``
        (from ``start_rollout``, returned with the result). The paper's network: ``out``
        itself, or z + out (times the residual gain) with ``ModelConfig.residual``."""
        if not self.config.residual:
            return out, carry
        if carry is None:
            return z + out, carry
        return z + out * carry, carry


def _stacked_lstm_weights(lstm: nn.LSTM) -> list[tuple[Tensor, Tensor]]:
    """Per layer, [W_ih W_hh]^T (in + H, 4H) and b_ih + b_hh (4H,) of an ``nn.LSTM``.

    The decoder runs one step at a time; ``nn.LSTM``'s per-call overhead dominates at these
    sizes, so the step is written out (``_lstm_cell``) on weights joined once per sequence.
    The module still owns the parameters (standard layout and count).
    """
    out = []
    for i in range(lstm.num_layers):
        w = torch.cat([getattr(lstm, f"weight_ih_l{i}"), getattr(lstm, f"weight_hh_l{i}")], 1)
        out.append((w.t(), getattr(lstm, f"bias_ih_l{i}") + getattr(lstm, f"bias_hh_l{i}")))
    return out


def _lstm_cell(x: Tensor, h: Tensor, c: Tensor, w: Tensor, b: Tensor) -> tuple[Tensor, Tensor]:
    """One LSTM step, PyTorch's gate order (i, f, g, o): x (B, in), h, c (B, H) -> h', c'."""
    gates = torch.addmm(b, torch.cat([x, h], dim=-1), w)  # (B, 4H)
    # Slices at constant offsets (the same views as ``chunk``): an exported graph then holds
    # four Slice nodes instead of recomputing the chunk size from the shape at every step.
    hidden = int(w.shape[1]) // 4
    i, f, g, o = (gates[:, k * hidden : (k + 1) * hidden] for k in range(4))  # (B, H) each
    c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(g)
    return torch.sigmoid(o) * torch.tanh(c), c


def _with(features: Tensor, cond: Tensor | None) -> Tensor:
    """features (B, T, F) with the per-window columns cond (B, C) appended at every step."""
    if cond is None:
        return features
    return torch.cat([features, cond.unsqueeze(1).expand(-1, features.shape[1], -1)], -1)


def _check_shapes(x_hist: Tensor, u_hist: Tensor, u_future: Tensor) -> None:
    ok = (
        x_hist.dim() == 3
        and u_hist.dim() == 3
        and u_future.dim() == 3
        and x_hist.shape[-1] == STATE_DIM
        and u_hist.shape[-1] == INPUT_DIM
        and u_future.shape[-1] == INPUT_DIM
        and u_hist.shape[:2] == x_hist.shape[:2]
        and u_future.shape[0] == x_hist.shape[0]
        and u_future.shape[1] >= 1
    )
    if not ok:
        raise ValueError(
            f"SlungLoadNet: expected x_hist (B, M, {STATE_DIM}), u_hist (B, M, {INPUT_DIM}), "
            f"u_future (B, N>=1, {INPUT_DIM}); got {tuple(x_hist.shape)}, "
            f"{tuple(u_hist.shape)}, {tuple(u_future.shape)}"
        )
