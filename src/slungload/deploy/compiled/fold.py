"""The one weight fold of the compiled paths: a network's weights rearranged for the batch-1
predictor (``predictor``) and the batched backend (``batched``) alike.

The arithmetic is the network's (``models.lstm_attention.SlungLoadNet`` and the architectures
built on it), rearranged exactly, once, in float64, then rounded to float32:

- the input standardisation is folded into the first embedding layer, so that the compiled
  decoder runs in physical units relative to the last measured position (``model.origin``);
- the head's first two Linears (no activation between them) are the network's own joined
  product (``OutputHead.joined``); a head of two Linears is their product;
- the residual gain ``delta_std`` (one without normalisation; the state's spread for an
  absolute head, whose mean is then added) is folded into the head's last layer, and its slack
  rows are dropped (they are for the loss only);
- the decoder's first LSTM layer is split into its context and embedding columns, so that the
  encoder outputs can be projected by the context columns once per window;
- the first embedding layer's columns on the constants a network may see
  (``ModelConfig.constants_input``) are kept apart: they are the same at every step of a
  window, so they fold into that window's first bias (``first_bias``), or into the folded
  bias itself when f's constants are fixed.

The physics-step network (``models.physics_step.PhysicsStepNet``) folds the same way; its
decoder step adds the folded correction to f(x_k, u_k, a_k) (``physics``), in the network's
own vehicle constants, with the load estimate it was trained with.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from ...config import VehicleParams
from ...layout import STATE_DIM
from ...models.lstm_attention import SlungLoadNet
from ...models.physics_step import PhysicsStepNet
from ...physics import VehicleConstants
from ...state import heading_basis
from .physics import load_filters
from .weights import ABSOLUTE, PHYSICS_STEP, RESIDUAL, FoldedWeights, first_bias

# What ``fold`` knows how to rearrange: architecture name -> the class a model must be.
_COMPILED_CLASSES: dict[str, type[SlungLoadNet]] = {
    cls.architecture: cls for cls in (SlungLoadNet, PhysicsStepNet)
}
COMPILED_ARCHITECTURES = tuple(_COMPILED_CLASSES)
_NO_HEADING = np.zeros((0, STATE_DIM, STATE_DIM))


def unsupported_architecture(model: nn.Module) -> str | None:
    """Why ``fold`` cannot rearrange ``model`` (its architecture), or None when it can."""
    name = getattr(model, "architecture", type(model).__name__)
    cls = _COMPILED_CLASSES.get(name)
    if cls is None or not isinstance(model, cls):
        return (
            f"deploy.compiled does not support the {name!r} architecture (it supports "
            f"{list(COMPILED_ARCHITECTURES)})"
        )
    return None


def fold(model: SlungLoadNet) -> FoldedWeights:
    """Rearrange ``model``'s weights for the compiled paths (see the module doc); an
    architecture it cannot rearrange is a ``ValueError`` naming it."""
    reason = unsupported_architecture(model)
    if reason is not None:
        raise ValueError(reason)
    cfg = model.config
    with torch.no_grad():
        d = {k: v.detach().double().cpu() for k, v in model.state_dict().items()}
        head = [
            (w.detach().double().cpu(), b.detach().double().cpu()) for w, b in model.head.joined()
        ]
    ms, ss = d["state_mean"], d["state_std"]
    gain, add_mean, mode = _output_gain(model, ms, ss)
    enc_emb, enc_ih, enc_hh, enc_b = _lstm(d, "encoder", cfg.num_layers)
    dec_0, dec_ih, dec_hh, dec_b = _lstm(d, "decoder", cfg.num_layers)
    h = cfg.hidden_size
    vehicle = VehicleConstants.of(getattr(model, "params", None) or VehicleParams())
    reference = VehicleConstants.of(getattr(model, "reference", None) or VehicleParams())
    embed, embed_constants = _embedding(d, len(cfg.embed_sizes))
    folded = FoldedWeights(
        embed=tuple((_f32(w), _f32(b)) for w, b in embed),
        head=tuple((_f32(w), _f32(b)) for w, b in _head(head, len(model.head.layers), gain)),
        enc_emb=_f32(enc_emb), enc_ih=_f32(enc_ih), enc_hh=_f32(enc_hh), enc_b=_f32(enc_b),
        att_w=_f32(d["attention.W.weight"]), att_u=_f32(d["attention.U.weight"]),
        att_v=_f32(d["attention.v.weight"][0]),
        dec_ctx=_f32(dec_0[:, :h]), dec_emb=_f32(dec_0[:, h:]), dec_ih=_f32(dec_ih),
        dec_hh=_f32(dec_hh), dec_b=_f32(dec_b),
        add_mean=_f32(add_mean), mode=mode,
        origin_shift=_f32(model.position_shift.double().cpu()),
        architecture=model.architecture,
        vehicle=vehicle,
        load_filters=load_filters(cfg.load_estimate, vehicle.dt),
        constants=getattr(cfg, "constants", "dataset"),
        embed_constants=_f32(embed_constants),
        reference=reference,
        heading=heading_basis(False).numpy() if cfg.heading_frame else _NO_HEADING,
    )  # fmt: skip
    if folded.constants != "window":  # f's constants fixed: the constants' columns, a fixed bias
        first = (folded.embed[0][0], first_bias(folded, vehicle))
        folded = folded._replace(embed=(first, *folded.embed[1:]),
                                 embed_constants=folded.embed_constants[:, :0])  # fmt: skip
    return folded


def _f32(t: Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.numpy(), dtype=np.float32)


def _embedding(d: dict[str, Tensor], layers: int) -> tuple[list[tuple[Tensor, Tensor]], Tensor]:
    """The embedding's (W, b) per layer, the first rewritten from the standardised inputs
    z = (x - o - mean) / std, v = (u - mean) / std onto x - o and u; and the first layer's
    columns on the constants (E0, C), C = 0 for a network that does not see them."""
    ms, ss, mu, su = d["state_mean"], d["state_std"], d["input_mean"], d["input_std"]
    w0, b0 = d["embed.layers.0.weight"], d["embed.layers.0.bias"]  # (E0, 17 + C) on (z, v, c)
    features = STATE_DIM + len(mu)
    first = torch.cat([w0[:, :STATE_DIM] / ss, w0[:, STATE_DIM:features] / su], 1)  # (x - o, u)
    embed = [(first, b0 - first[:, :STATE_DIM] @ ms - first[:, STATE_DIM:] @ mu)]
    embed += [(d[f"embed.layers.{i}.weight"], d[f"embed.layers.{i}.bias"])
              for i in range(1, layers)]  # fmt: skip
    return embed, w0[:, features:]


def _head(
    joined: list[tuple[Tensor, Tensor]], layers: int, gain: Tensor
) -> list[tuple[Tensor, Tensor]]:
    """The head's (W, b) per layer from its joined layers (``OutputHead.joined``) and its
    number of Linears: a head of two (no activation between them) multiplied into one, the
    last layer's state rows scaled by ``gain`` (its slack rows dropped)."""
    head = list(joined)
    if layers == 2:  # Linear -> Linear, no activation: their product
        (wa, ba), (wb, bb) = head
        head = [(wb @ wa, wb @ ba + bb)]
    wl, bl = head[-1]
    head[-1] = (wl[:STATE_DIM] * gain[:, None], bl[:STATE_DIM] * gain)
    return head


def _lstm(d: dict[str, Tensor], prefix: str, layers: int) -> tuple[Tensor, ...]:
    """A stacked LSTM's weights: layer 0's input weights (G, in), the input weights of the
    layers above (L, G, H) (layer 0's slot zero), the recurrent weights (L, G, H) and the
    summed biases (L, G)."""
    ih = [d[f"{prefix}.weight_ih_l{i}"] for i in range(layers)]
    hh = torch.stack([d[f"{prefix}.weight_hh_l{i}"] for i in range(layers)])
    b = torch.stack([d[f"{prefix}.bias_ih_l{i}"] + d[f"{prefix}.bias_hh_l{i}"]
                     for i in range(layers)])  # fmt: skip
    upper = torch.stack([torch.zeros_like(hh[0])] + ih[1:])  # layer 0's input unused
    return ih[0], upper, hh, b


def _output_gain(net: SlungLoadNet, ms: Tensor, ss: Tensor) -> tuple[Tensor, Tensor, int]:
    """What scales the head's state rows into a physical update, what is added to them, and
    the update's mode: the residual gain delta_std (one without normalisation) for residual
    heads and the physics step, the state's spread and mean for an absolute head."""
    cfg = net.config
    mode = PHYSICS_STEP if isinstance(net, PhysicsStepNet) else RESIDUAL
    if not cfg.residual:
        return ss, ms, ABSOLUTE
    gain = net.delta_std.detach().double().cpu() if cfg.normalize else torch.ones_like(ms)
    return gain, torch.zeros_like(ms), mode
