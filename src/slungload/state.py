"""Quaternion and state helpers in torch, over the layout of ``layout.py``.

The column layout (``STATE_DIM``, the named slices ``POS`` ... ``LOAD_RATE``, ``GROUPS``,
``STATE_NAMES``, the file layout's ``STATE_COLUMNS``) lives in ``layout.py``, importable without
torch; it is re-exported here, so ``from slungload.state import POS`` keeps working. Quaternions
are w-x-y-z inside the package, x-y-z-w in the data files (and in roma); the package reorders
them at the edges (``quat_xyzw_to_wxyz``). World frame is z up.
"""

from __future__ import annotations

import functools

import roma
import torch
from torch import Tensor

from .layout import (
    AUX_DIM,
    GROUP_UNITS,
    GROUPS,
    HISTORY_COLUMNS,
    HISTORY_DIM,
    INPUT_DIM,
    INPUT_NAMES,
    LOAD_POS,
    LOAD_RATE,
    LOAD_VEL,
    POS,
    QUAT,
    RATES,
    STATE_COLUMNS,
    STATE_DIM,
    STATE_NAMES,
    THRUST,
    VEL,
    split_state,
)

__all__ = [  # the layout's names, re-exported, then this module's own
    "AUX_DIM", "GROUPS", "GROUP_UNITS", "HISTORY_COLUMNS", "HISTORY_DIM", "INPUT_DIM",
    "INPUT_NAMES", "LOAD_POS", "LOAD_RATE", "LOAD_VEL", "POS", "QUAT", "RATES", "STATE_COLUMNS",
    "STATE_DIM", "STATE_NAMES", "THRUST", "VEL",
    "body_z", "group_errors", "join_state", "quat_conj", "quat_continuous", "quat_error",
    "quat_from_rotvec", "quat_identity", "quat_mul", "quat_normalize", "quat_to_rotmat",
    "quat_wxyz_to_xyzw", "quat_xyzw_to_wxyz", "rotate_about_z", "heading_twist",
    "heading_turn", "to_heading_frame", "from_heading_frame", "split_input", "split_state",
    "with_unit_quaternion",
]  # fmt: skip


def join_state(p: Tensor, v: Tensor, q: Tensor, p_load: Tensor) -> Tensor:
    """Inverse of ``split_state``: (..., 3), (..., 3), (..., 4), (..., 3) -> (..., 13)."""
    return torch.cat([p, v, q, p_load], dim=-1)


def split_input(u: Tensor) -> tuple[Tensor, Tensor]:
    """(..., 4) -> thrust (...,) in N, body rates (..., 3) in rad/s."""
    return u[..., THRUST].squeeze(-1), u[..., RATES]


# --- quaternions (w-x-y-z inside the package; roma works in x-y-z-w) ---------------------


def quat_wxyz_to_xyzw(q: Tensor) -> Tensor:
    """(..., 4) w-x-y-z -> x-y-z-w."""
    return roma.quat_wxyz_to_xyzw(q)


def quat_xyzw_to_wxyz(q: Tensor) -> Tensor:
    """(..., 4) x-y-z-w -> w-x-y-z."""
    return roma.quat_xyzw_to_wxyz(q)


def quat_mul(q1: Tensor, q2: Tensor) -> Tensor:
    """Hamilton product q1 (x) q2 of w-x-y-z quaternions, (..., 4)."""
    return quat_xyzw_to_wxyz(roma.quat_product(quat_wxyz_to_xyzw(q1), quat_wxyz_to_xyzw(q2)))


def quat_conj(q: Tensor) -> Tensor:
    """Conjugate of w-x-y-z quaternions (the inverse for unit ones), (..., 4)."""
    return torch.cat([q[..., :1], -q[..., 1:]], dim=-1)


def quat_identity(*shape: int, dtype=None, device=None) -> Tensor:
    """Identity quaternion (1, 0, 0, 0) broadcast to (*shape, 4)."""
    q = torch.zeros(*shape, 4, dtype=dtype, device=device)
    q[..., 0] = 1.0
    return q


def quat_error(q_hat: Tensor, q: Tensor) -> Tensor:
    """The paper's attitude error e(q_hat, q) = q_hat (x) q^{-1} - q_id, (..., 4).

    ``q^{-1}`` is taken as the conjugate, so ``q`` should be unit norm; ``q_hat`` need not be.
    """
    d = quat_mul(q_hat, quat_conj(q))
    return d - quat_identity(*d.shape[:-1], dtype=d.dtype, device=d.device)


def quat_to_rotmat(q: Tensor) -> Tensor:
    """w-x-y-z quaternion (..., 4) -> rotation matrix (..., 3, 3), body -> world.

    The quaternion is normalised first, so a network output that drifted off unit norm still
    gives a rotation.
    """
    return roma.unitquat_to_rotmat(quat_wxyz_to_xyzw(quat_normalize(q)))


def body_z(q: Tensor) -> Tensor:
    """The body z axis (the thrust direction) in the world frame, (..., 3), of w-x-y-z
    quaternions (..., 4), normalised first: the last column of ``quat_to_rotmat(q)`` with the
    same arithmetic (roma's), without the other six entries (the physics step's hot path)."""
    w, x, y, z = quat_normalize(q).unbind(-1)
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xz, yw, yz, xw = x * z, y * w, y * z, x * w
    return torch.stack((2 * (xz + yw), 2 * (yz - xw), -x2 - y2 + z2 + w2), dim=-1)


def quat_normalize(q: Tensor, eps: float = 1e-12) -> Tensor:
    """Unit quaternion with the same direction, (..., 4)."""
    return q / q.norm(dim=-1, keepdim=True).clamp_min(eps)


def quat_from_rotvec(r: Tensor) -> Tensor:
    """Rotation vector (..., 3), rad -> unit quaternion w-x-y-z (..., 4): exp(S(r))."""
    return quat_xyzw_to_wxyz(roma.rotvec_to_unitquat(r))


def quat_continuous(q: Tensor) -> Tensor:
    """Flip signs along the time axis (-2) so consecutive quaternions have q_k . q_{k-1} >= 0.

    q and -q are the same rotation; a sign jump would look like a huge error to the network.
    Input (..., T, 4); the first step's sign is kept.
    """
    dots = (q[..., 1:, :] * q[..., :-1, :]).sum(-1)
    flips = torch.cumsum((dots < 0).to(torch.int64), dim=-1) % 2
    sign = torch.ones_like(q[..., :, 0])
    sign[..., 1:] = 1.0 - 2.0 * flips.to(q.dtype)
    return q * sign.unsqueeze(-1)


def rotate_about_z(states: Tensor, aux: Tensor, yaw: Tensor) -> tuple[Tensor, Tensor]:
    """Turn the whole scene about the world's vertical axis by ``yaw`` rad.

    A symmetry of the dynamics (gravity is along z; thrust and body rates live in the body
    frame, so inputs are unchanged): positions, velocities, the load state and the attitude turn
    together. states (..., 13), aux (..., 6), yaw broadcastable to states.shape[:-1].
    """
    yaw = torch.as_tensor(yaw, dtype=states.dtype, device=states.device)
    yaw = yaw.expand(states.shape[:-1])
    c, s = torch.cos(yaw).unsqueeze(-1), torch.sin(yaw).unsqueeze(-1)

    def turn(vec: Tensor) -> Tensor:  # (..., 3)
        x, y, z = vec[..., :1], vec[..., 1:2], vec[..., 2:]
        return torch.cat([c * x - s * y, s * x + c * y, z], dim=-1)

    half = 0.5 * yaw.unsqueeze(-1)
    zero = torch.zeros_like(half)
    q_yaw = torch.cat([torch.cos(half), zero, zero, torch.sin(half)], dim=-1)
    p, v, q, p_load = split_state(states)
    out = join_state(turn(p), turn(v), quat_mul(q_yaw, q), turn(p_load))
    return out, torch.cat([turn(aux[..., LOAD_VEL]), turn(aux[..., LOAD_RATE])], dim=-1)


def heading_twist(q: Tensor) -> Tensor:
    """The attitude's turn about the world's vertical, a unit quaternion (w, 0, 0, z) / norm
    (..., 4) of w-x-y-z quaternions q (..., 4): q's twist about z. Turning the world by psi
    about z turns it by psi (it is equivariant), so turning a scene by its inverse gives every
    heading the same frame. Only arithmetic and a square root (exports to any graph);
    undefined for an attitude upside down (w = z = 0), never met in flight."""
    w, z = q[..., :1], q[..., 3:]
    norm = torch.sqrt(w * w + z * z).clamp_min(1e-12)
    zero = torch.zeros_like(w)
    return torch.cat([w / norm, zero, zero, z / norm], dim=-1)


def heading_turn(twist: Tensor, *, errors: bool = False) -> Tensor:
    """The turn of a state about z by ``twist`` (..., 4), a unit quaternion (a, 0, 0, b), as an
    orthogonal matrix (..., 13, 13) acting on state columns: positions and velocities rotated by
    the angle of cosine a^2 - b^2 and sine 2 a b, the attitude left-multiplied by the twist. One
    matrix product then turns every row of a window (``to_heading_frame``).

    ``errors``: the turn of 13 state *errors* instead, whose quaternion block is an attitude
    error q1 (x) q2^-1 - q_id (``quat_error``; the slack variables): a turn of the world
    conjugates it, so its w and z stay and its x and y rotate as a vector's do."""
    a, b = twist[..., 0, None, None], twist[..., 3, None, None]
    c, s = a * a - b * b, 2.0 * a * b
    basis = _turn_basis(twist.dtype, twist.device, errors)
    if errors:
        return basis[0] + c * basis[1] + s * basis[2]
    return basis[0] + c * basis[1] + s * basis[2] + a * basis[3] + b * basis[4]


@functools.cache  # never freed: a captured CUDA graph may read one
def _turn_basis(dtype: torch.dtype, device: torch.device, errors: bool) -> Tensor:
    """(5, 13, 13): ``heading_turn``'s matrix = B0 + c B1 + s B2 (+ a B3 + b B4 for states),
    made once per dtype and device (a copy at every call would stop a CUDA graph capture; a
    plain tensor even under ``torch.inference_mode``, as ``load_state._fit_coefficients``)."""
    with torch.inference_mode(False):
        return heading_basis(errors).to(dtype=dtype, device=device)


def heading_basis(errors: bool) -> Tensor:
    """(5, 13, 13) float64: ``heading_turn``'s matrix = B0 + c B1 + s B2 (+ a B3 + b B4)."""
    out = torch.zeros(5, STATE_DIM, STATE_DIM, dtype=torch.float64)
    w, qx, qy, qz = range(QUAT.start, QUAT.stop)
    vectors = [range(v.start, v.stop) for v in (POS, VEL, LOAD_POS)]
    if errors:  # an attitude error's (x, y, z) turns as a vector, its w stays
        vectors.append(range(qx, qz + 1))
        out[0, w, w] = 1.0
    for x, y, z in vectors:
        out[0, z, z] = 1.0
        out[1, x, x] = out[1, y, y] = 1.0  # c
        out[2, x, y], out[2, y, x] = -1.0, 1.0  # s
    if not errors:  # (a, 0, 0, b) (x) q = (a w - b z, a x - b y, a y + b x, a z + b w)
        for i in (w, qx, qy, qz):
            out[3, i, i] = 1.0
        out[4, w, qz], out[4, qx, qy], out[4, qy, qx], out[4, qz, w] = -1.0, -1.0, 1.0, 1.0
    return out


def to_heading_frame(states: Tensor, turn: Tensor) -> Tensor:
    """States (..., T, 13) turned about the world's vertical by the inverse of ``turn``
    (``heading_turn`` of a ``heading_twist``, (..., 13, 13) broadcast over the rows): a scene
    whose heading was the twist's now heads along x."""
    return states @ turn  # each row times turn^T^-1 = turn (orthogonal)


def from_heading_frame(states: Tensor, turn: Tensor) -> Tensor:
    """The inverse of ``to_heading_frame``: states (..., T, 13) (or any 13 state rows, such as
    slack variables) turned back by ``turn`` (..., 13, 13)."""
    return states @ turn.transpose(-1, -2)


def with_unit_quaternion(states: Tensor) -> Tensor:
    """States (..., 13) with the quaternion block scaled to unit norm (for evaluation)."""
    out = states.clone()
    out[..., QUAT] = quat_normalize(states[..., QUAT])
    return out


def group_errors(pred: Tensor, true: Tensor) -> dict[str, Tensor]:
    """Error norm per group: pred, true (W, N, 13) -> {group: (W, N)}, float64.

    Quaternion: || q_hat (x) q^-1 - q_id ||; the others: the Euclidean norm of the difference.
    """
    if pred.shape != true.shape:
        raise ValueError(f"prediction {tuple(pred.shape)} and truth {tuple(true.shape)} differ")
    pred, true = pred.double(), true.double()
    errors = {}
    for name, sl in GROUPS.items():
        if sl == QUAT:
            diff = quat_error(pred[..., sl], true[..., sl])
        else:
            diff = pred[..., sl] - true[..., sl]
        errors[name] = diff.norm(dim=-1)
    return errors
