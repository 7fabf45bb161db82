"""The folded weights of the compiled paths (``fold`` makes them from a network, ``archive``
reads them from a file): torch-free, so that the onboard path can run them without torch.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ...layout import STATE_DIM
from ...vehicle_constants import VehicleConstants, constant_ratios

# The decoder's state update (``FoldedWeights.mode``): x_{k+1} = x_k + out_k (residual),
# out_k + add_mean (absolute), f(x_k, u_k, a_k) + out_k (the physics step).
RESIDUAL, ABSOLUTE, PHYSICS_STEP = 0, 1, 2


class FoldedWeights(NamedTuple):
    """A network's weights for the compiled paths: float32 numpy arrays, C order; matrices
    (out, in) as torch's Linear. Rows of the state blocks are in the package layout (q
    w-x-y-z); E = the last embedding width, H = LSTM width, L = LSTM layers, G = 4H gates in
    PyTorch's order (i, f, g, o)."""

    # (W (out, in), b (out,)) per layer, GELU after each; the first on (x - origin, u), in
    # physical units.
    embed: tuple[tuple[np.ndarray, np.ndarray], ...]
    # (W, b) per layer, GELU after each but the last; the last (13, .): the state rows, scaled.
    head: tuple[tuple[np.ndarray, np.ndarray], ...]
    enc_emb: np.ndarray  # (G, E) encoder layer 0 on the embedding
    enc_ih: np.ndarray  # (L, G, H) encoder input weights of layers >= 1 (layer 0's zero)
    enc_hh: np.ndarray  # (L, G, H)
    enc_b: np.ndarray  # (L, G) b_ih + b_hh
    att_w: np.ndarray  # (H, H) keys W enc
    att_u: np.ndarray  # (H, H) query U h
    att_v: np.ndarray  # (H,)
    dec_ctx: np.ndarray  # (G, H) decoder layer 0 on the context
    dec_emb: np.ndarray  # (G, E) decoder layer 0 on the embedding
    dec_ih: np.ndarray  # (L, G, H) decoder input weights of layers >= 1 (layer 0's zero)
    dec_hh: np.ndarray  # (L, G, H)
    dec_b: np.ndarray  # (L, G)
    add_mean: np.ndarray  # (13,) added to an absolute head's output (zero otherwise)
    mode: int  # the decoder's state update: RESIDUAL, ABSOLUTE or PHYSICS_STEP
    origin_shift: np.ndarray  # (3, 13) vehicle position -> origin offset (``model.origin``)
    architecture: str  # the model's name in ``models.MODELS`` (one of COMPILED_ARCHITECTURES)
    vehicle: VehicleConstants  # f's constants as floats (the model's; defaults where f is unused)
    # The smoothed load estimate's weights (``physics.load_filters``), float64; (0, 0) for the
    # backward difference.
    load_filters: np.ndarray
    # "window": f runs with each window's constants (``physics.adapted_constants`` of the
    # history, in place of ``vehicle``'s cable length and load mass); "dataset": ``vehicle``.
    constants: str = "dataset"
    # (E0, C) the first embedding layer's columns on f's constants (C = 0 unless the network
    # sees them) and the constants they are measured against (``PhysicsStepNet.reference``).
    embed_constants: np.ndarray = np.zeros((0, 0), np.float32)
    reference: VehicleConstants | None = None
    # (5, 13, 13) float64 ``state.heading_turn``'s basis for a network that works in the heading
    # frame (``ModelConfig.heading_frame``); (0, 13, 13) for one that does not.
    heading: np.ndarray = np.zeros((0, STATE_DIM, STATE_DIM))


def first_bias(w: FoldedWeights, vehicle: VehicleConstants) -> np.ndarray:
    """The first embedding layer's bias (E0,) for a window whose f runs with ``vehicle``: the
    folded bias plus the constants' columns times ``constant_ratios`` (float64 sum, float32
    out); the folded bias itself for a network that does not see its constants."""
    bias = w.embed[0][1]
    if w.embed_constants.shape[1] == 0:
        return bias
    ratios = np.array(constant_ratios(vehicle, w.reference), np.float64)
    return (bias + w.embed_constants.astype(np.float64) @ ratios).astype(np.float32)


def heading_turn(w: FoldedWeights, q: np.ndarray) -> np.ndarray | None:
    """``state.heading_turn`` of ``state.heading_twist`` of the attitude q (4,) (w-x-y-z),
    numpy float64 (13, 13), for a network that works in the heading frame; None otherwise."""
    if w.heading.shape[0] == 0:
        return None
    norm = max(float(np.hypot(q[0], q[3])), 1e-12)
    a, b = float(q[0]) / norm, float(q[3]) / norm
    basis = w.heading
    return (
        basis[0] + (a * a - b * b) * basis[1] + 2.0 * a * b * basis[2] + a * basis[3] + b * basis[4]
    )
