"""Rotations and frame conventions in numpy: the package's one numpy home for quaternion
products, rotation matrices and the conversion of other frames to the package's (world z up,
body z up, FLU). The simulator and the log readers use these; ``state`` holds the batched
torch versions for the models.

The log readers (``data.readers``) convert recorded flights with these helpers, and a
vehicle's own control loop converts its autopilot's measurements with the same ones before
calling the onboard controller (``control.mppi``; docs/control.md): this module imports
numpy alone, no torch.

The package's world frame is any z-up frame (ENU in ROS terms; the dynamics do not care where
x points) and its body frame has z along the thrust (FLU: forward, left, up, ROS REP 103).
PX4 and many autopilots use NED for the world and FRD for the body:

- a world vector in NED becomes ENU as (x, y, z) -> (y, x, -z): a rotation of pi about
  (1, 1, 0) / sqrt 2;
- a body vector in FRD becomes FLU as (x, y, z) -> (x, -y, -z): a rotation of pi about x
  (body rates, being vectors in the body frame, convert the same way);
- an attitude q (body -> world) becomes q_ENU<-NED (x) q (x) q_FLU<-FRD^-1.

Quaternions here are numpy arrays w-x-y-z, shape (..., 4).
"""

from __future__ import annotations

import math

import numpy as np

from .layout import LOAD_POS, POS

WORLD_FRAMES = ("enu", "ned")  # "enu": any z-up world frame, taken as it is
BODY_FRAMES = ("flu", "frd")

_S = np.sqrt(0.5)
Q_ENU_FROM_NED = np.array([0.0, _S, _S, 0.0])  # w-x-y-z, pi about (1, 1, 0)/sqrt 2
Q_FLU_FROM_FRD = np.array([0.0, 1.0, 0.0, 0.0])  # pi about x


def quat_multiply(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Hamilton product of w-x-y-z quaternions, broadcast over leading axes."""
    w1, x1, y1, z1 = np.moveaxis(np.asarray(q1, float), -1, 0)
    w2, x2, y2, z2 = np.moveaxis(np.asarray(q2, float), -1, 0)
    return np.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        axis=-1,
    )


def quat_from_rotvec(r: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) rad -> unit quaternion w-x-y-z (4,): exp(r / 2)."""
    angle = math.sqrt(r @ r)
    if angle < 1e-12:
        return np.array([1.0, 0.5 * r[0], 0.5 * r[1], 0.5 * r[2]])
    s = math.sin(0.5 * angle) / angle
    return np.array([math.cos(0.5 * angle), s * r[0], s * r[1], s * r[2]])


def rotvec_from_matrix(r: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) rad of a rotation matrix (3, 3) (angles below pi): the log map,
    the inverse of ``quat_from_rotvec`` followed by ``rotation_matrix``."""
    cos = max(-1.0, min(1.0, 0.5 * (r[0, 0] + r[1, 1] + r[2, 2] - 1.0)))
    angle = math.acos(cos)
    axis = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    s = math.sin(angle)
    if s < 1e-9:
        return 0.5 * axis
    return axis * (0.5 * angle / s)


def rotation_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 3, 3) body -> world rotation of w-x-y-z quaternions (..., 4), normalised first;
    its columns are the body axes in the world."""
    q = np.asarray(q, float)
    w, x, y, z = np.moveaxis(q / np.sqrt(np.sum(q * q, axis=-1, keepdims=True)), -1, 0)
    rows = (
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def quat_from_matrix(r: np.ndarray) -> np.ndarray:
    """Unit quaternion w-x-y-z (4,) of a rotation matrix (3, 3), any angle up to pi
    (Shepperd: from the largest of w, x, y, z, so no division by a small number); the
    inverse of ``rotation_matrix``, up to sign."""
    r = np.asarray(r, float)
    trace = r[0, 0] + r[1, 1] + r[2, 2]
    diagonal = 2.0 * np.diag(r) - trace
    squares = 1.0 + np.array([trace, *diagonal])  # 4 w^2, 4 x^2, 4 y^2, 4 z^2
    k = int(np.argmax(squares))
    big = 0.5 * math.sqrt(max(squares[k], 0.0))  # the largest component, >= 1/2
    sums = {  # 4 times the products of the largest component with the others
        0: (r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]),
        1: (r[2, 1] - r[1, 2], r[0, 1] + r[1, 0], r[0, 2] + r[2, 0]),
        2: (r[0, 2] - r[2, 0], r[0, 1] + r[1, 0], r[1, 2] + r[2, 1]),
        3: (r[1, 0] - r[0, 1], r[0, 2] + r[2, 0], r[1, 2] + r[2, 1]),
    }[k]
    others = [s / (4 * big) for s in sums]
    q = np.array(others[:k] + [big] + others[k:])
    return q / np.linalg.norm(q)


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    return np.asarray(q, float) * np.array([1.0, -1.0, -1.0, -1.0])


def quat_continuous(q: np.ndarray) -> np.ndarray:
    """Signs flipped along the time axis (-2) so that consecutive quaternions have
    q_k . q_{k-1} >= 0 (q and -q are one rotation; a sign jump would look like a huge error to
    a network); (..., T, 4), the first step's sign kept. ``state.quat_continuous`` in torch."""
    dots = (q[..., 1:, :] * q[..., :-1, :]).sum(-1)
    flips = np.cumsum(dots < 0, axis=-1) % 2
    sign = np.ones(q.shape[:-1])
    sign[..., 1:] = 1.0 - 2.0 * flips
    return q * sign[..., None]


def world_vectors(v: np.ndarray, frame: str) -> np.ndarray:
    """(..., 3) positions or velocities in ``frame`` ("enu" or "ned") -> z-up world."""
    _check(frame, WORLD_FRAMES, "world")
    v = np.asarray(v, float)
    return v.copy() if frame == "enu" else np.stack([v[..., 1], v[..., 0], -v[..., 2]], axis=-1)


def body_vectors(w: np.ndarray, frame: str) -> np.ndarray:
    """(..., 3) body rates (or any body vector) in ``frame`` ("flu" or "frd") -> FLU."""
    _check(frame, BODY_FRAMES, "body")
    w = np.asarray(w, float)
    return w.copy() if frame == "flu" else w * np.array([1.0, -1.0, -1.0])


def attitudes(q: np.ndarray, world: str, body: str) -> np.ndarray:
    """(..., 4) w-x-y-z body -> world rotations in the ``world`` and ``body`` frames -> the
    package's (z-up world, FLU body)."""
    _check(world, WORLD_FRAMES, "world")
    _check(body, BODY_FRAMES, "body")
    q = np.asarray(q, float)
    if world == "ned":
        q = quat_multiply(Q_ENU_FROM_NED, q)
    if body == "frd":
        q = quat_multiply(q, quat_conjugate(Q_FLU_FROM_FRD))
    return q


def attitudes_to(q: np.ndarray, world: str, body: str) -> np.ndarray:
    """(..., 4) w-x-y-z attitudes in the package's frames -> the ``world`` and ``body``
    frames: the inverse of ``attitudes`` (what a simulated autopilot reports in NED / FRD)."""
    _check(world, WORLD_FRAMES, "world")
    _check(body, BODY_FRAMES, "body")
    q = np.asarray(q, float)
    if world == "ned":
        q = quat_multiply(quat_conjugate(Q_ENU_FROM_NED), q)
    if body == "frd":
        q = quat_multiply(q, Q_FLU_FROM_FRD)
    return q


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors (..., 3) by unit quaternions (..., 4) w-x-y-z: R(q) v."""
    q = np.asarray(q, float)
    v = np.asarray(v, float)
    u, w = q[..., 1:], q[..., :1]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def slerp(t: np.ndarray, times: np.ndarray, quats: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (n, 4) sampled at increasing
    ``times`` (n,), at the instants ``t`` (m,) inside [times[0], times[-1]]; the shorter arc
    (q and -q are the same rotation)."""
    times = np.asarray(times, float)
    quats = np.asarray(quats, float)
    t = np.asarray(t, float)
    if len(times) == 1:
        return np.repeat(quats, len(t), axis=0)
    i = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
    u = np.clip((t - times[i]) / (times[i + 1] - times[i]), 0.0, 1.0)[:, None]
    q0, q1 = quats[i], quats[i + 1].copy()
    dot = np.sum(q0 * q1, axis=-1)
    q1[dot < 0] *= -1.0
    dot = np.abs(dot)[:, None]
    angle = np.arccos(np.clip(dot, -1.0, 1.0))
    sin = np.sin(angle)
    near = sin < 1e-9
    safe = np.where(near, 1.0, sin)
    a = np.where(near, 1.0 - u, np.sin((1.0 - u) * angle) / safe)
    b = np.where(near, u, np.sin(u * angle) / safe)
    out = a * q0 + b * q1
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def swing_angle(states: np.ndarray) -> np.ndarray:
    """Angle (...,) rad of the cable, load minus vehicle position, from straight down, for
    states (..., 13) in the package's layout (world z up; 0: hanging still, pi/2: horizontal)."""
    cable = states[..., LOAD_POS] - states[..., POS]
    return np.arctan2(np.hypot(cable[..., 0], cable[..., 1]), -cable[..., 2])


def _check(frame: str, known: tuple[str, ...], what: str) -> None:
    if frame not in known:
        raise ValueError(f"unknown {what} frame {frame!r}; known: {', '.join(known)}")
