"""The MPC's cost, numpy only: what a predicted state sequence and its plan cost
(``trajectory_cost``), and what the state terms hold the vehicle and the cable to
(``MPCConfig.cost``: ``COSTS``; the payload-first target, ``payload_first``). The controller
(``mppi``) and the flown-cost report (``closed_loop.realized_cost``) share it.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from .. import frames
from ..layout import INPUT_DIM, LOAD_POS, POS, QUAT, VEL

# The MPC's cost options (``MPCConfig.cost``), first the default.
COSTS: dict[str, str] = {
    "vehicle": "the vehicle at the reference, the load below it on a vertical cable",
    "payload": "the load on the reference's path, the vehicle and the cable where that path's "
    "acceleration needs them (turns are not penalised for the swing they need)",
}


# What ``MPCConfig.lean`` and ``MPCConfig.shape`` do, for the help of each command that flies the
# MPC.
LEAN_HELP = ("with the payload cost: the reference's acceleration the cable's direction "
             "follows, averaged over X x sqrt(cable length / g) each way (the cable leans only "
             "as fast as the load swings; 0: the reference's own; docs/control.md)")  # fmt: skip
SHAPE_HELP = ("with the payload cost: the reference's jumps (position changes its velocity does "
              "not account for, as a setpoint's steps) spread into a path the load can follow, "
              "over X x sqrt(max(cable length, jump) / g) each way, which the cost tracks (0: "
              "the jumps as they are; docs/control.md)")  # fmt: skip
# m a row: a reference position change its velocity leaves less than this unaccounted for is
# the central differences' error on a smooth path (at most ~1 mm, at the roll doublets'
# acceleration switches), not a jump (``jumps``)
JUMP_TOL = 2e-3


def cost_words(cost: str, lean: float = 0.0, shape: float = 0.0) -> str:
    """The MPC's cost as a report names it: "cost vehicle", "cost payload (lean 1, shape 1)"."""
    options = [f"{name} {value:g}" for name, value in (("lean", lean), ("shape", shape)) if value]
    return f"cost {cost}" + (f" ({', '.join(options)})" if options else "")


class ReferenceAhead(NamedTuple):
    """The reference at the N steps ahead, x_{k+1} ... x_{k+N} (world frame, z up): the
    vehicle's; the load's is l e3 below (``MPCConfig.cost`` "payload" reads it as the load's
    path, and needs its acceleration)."""

    position: np.ndarray  # (N, 3) m
    velocity: np.ndarray  # (N, 3) m/s
    yaw: np.ndarray  # (N,) rad
    acceleration: np.ndarray | None = None  # (N, 3) m/s^2


class Shape(NamedTuple):
    """How the payload cost spreads a reference's jumps (``shaped_jumps``): ``MPCConfig.shape``
    and the cost's cable length, gravity, and the reference rows' spacing."""

    factor: float  # MPCConfig.shape; 0: the jumps as they are
    cable_length: float  # m
    gravity: float  # m/s^2
    dt: float  # s


class VehicleTarget(NamedTuple):
    """What the payload-first cost holds the vehicle and the cable to at the N steps ahead
    (``payload_first``)."""

    position: np.ndarray  # (N, 3) m
    velocity: np.ndarray  # (N, 3) m/s
    offset: np.ndarray  # (N, 2) m: the load's horizontal offset from the vehicle, l q_xy


def payload_first(ref: ReferenceAhead, cable_length: float, gravity: float) -> VehicleTarget:
    """The vehicle's reference from the load's path (differential flatness of the slung load,
    Sreenath, Lee and Kumar 2013): the load at p_L = ref.position - l e3 with acceleration a_L
    (``ref.acceleration``) hangs along q = -(a_L + g e3) / |a_L + g e3| (unit, vehicle to
    load), so the vehicle belongs at p_L - l q, with the load offset l q_xy from it
    horizontally. Its velocity target is the load's, v_L: the cable's turning rate -l dq/dt is
    left out, because a reference whose acceleration jumps (a doublet, a step's corner) would
    ask for an unbounded one (with it, the roll doublets' load error doubled at N = 15 on
    tuning seeds; docs/control.md). A reference without acceleration is a ValueError."""
    if ref.acceleration is None:
        raise ValueError(
            "the payload-first cost needs the reference's acceleration (ReferenceAhead"
            ".acceleration, (N, 3) m/s^2)"
        )
    pull = ref.acceleration + np.array([0.0, 0.0, gravity])
    q = -pull / np.maximum(np.linalg.norm(pull, axis=-1, keepdims=True), 1e-6)
    load = ref.position - np.array([0.0, 0.0, cable_length])
    return VehicleTarget(load - cable_length * q, ref.velocity, cable_length * q[:, :2])


def cost_target(
    cfg: Any, ref: ReferenceAhead, cable_length: float, gravity: float
) -> VehicleTarget | None:
    """What ``cfg``'s cost (``cfg`` an ``mppi.MPCConfig``) holds the vehicle and the cable to
    along ``ref``: ``payload_first`` for the "payload" cost, None (the reference itself, a
    vertical cable) for "vehicle"."""
    if cfg.cost != "payload":
        return None
    return payload_first(ref, cable_length, gravity)


def shape_of(cfg: Any, cable_length: float, gravity: float, dt: float) -> Shape:
    """``cfg``'s (an ``mppi.MPCConfig``) shape with the cost's cable length, for rows dt s
    apart."""
    return Shape(cfg.shape, cable_length, gravity, dt)


def lean_rows(cfg: Any, cable_length: float, gravity: float, dt: float) -> float:
    """The time constant, in reference rows dt s apart, over which ``cfg``'s cost (``cfg`` an
    ``mppi.MPCConfig``, which takes a lean with the "payload" cost only) averages the
    reference's acceleration: ``cfg.lean`` x sqrt(l / g), the load's swing; 0: the rows as
    they are."""
    return cfg.lean * math.sqrt(cable_length / gravity) / dt


def jumps(position: np.ndarray, velocity: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The jumps of a whole flight's reference position (T, 3) m, rows dt s apart: the row
    changes its velocity (T, 3) m/s leaves more than ``JUMP_TOL`` unaccounted for
    (trapezoids; a setpoint's steps, a path clipped to the arena). Returns the rows each lands
    on (m,) and its size (m, 3) m; none for a path whose velocity is its position's."""
    change = np.diff(position, axis=0) - 0.5 * dt * (velocity[1:] + velocity[:-1])
    at = np.flatnonzero(np.linalg.norm(change, axis=-1) >= JUMP_TOL)
    return at + 1, change[at]


def leaned(acceleration: np.ndarray, rows: np.ndarray, lean: float) -> np.ndarray:
    """Rows ``rows`` (n,) of a whole flight's acceleration (T, 3), each averaged about its row
    with weights exp(-|j| / lean) over the rows j away (zero phase: a first-order low-pass
    run forward and backward; the flight's first and last rows held beyond its ends; cut
    where the weights fall below exp(-8)); lean 0: the rows as they are. (n, 3), float64.
    From the whole flight, not a window: a target that moved with the window would change from
    one control step to the next."""
    if lean == 0:
        return np.array(acceleration[rows], dtype=float)
    j = np.arange(-math.ceil(8 * lean), math.ceil(8 * lean) + 1)
    w = np.exp(-np.abs(j) / lean)
    near = np.clip(rows[:, None] + j, 0, len(acceleration) - 1)  # (n, 2J + 1)
    return np.einsum("j,njd->nd", w / w.sum(), np.asarray(acceleration, dtype=float)[near])


def shaped_jumps(
    ref,
    rows: np.ndarray,
    shape: float,
    cable_length: float,
    gravity: float,
    dt: float,
    found: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What ``shape`` (``MPCConfig.shape``) adds to a whole flight's reference at rows ``rows``
    (n,) (rows dt s apart): each jump (``jumps``) taken out and put back as a path, its
    size times the Laplace distribution's CDF about the jump with scale tau = shape x
    sqrt(max(l, |jump|) / g): no lag (half way at the jump), the load's swing time, and for a
    jump longer than the cable the time that keeps the path's peak acceleration at
    g / (2 shape^2) (the cable leaning atan(1 / (2 shape^2)), 27 deg at shape 1). Position
    (n, 3) m, velocity (n, 3) m/s, acceleration (n, 3) m/s^2 to add, float64; zeros without
    jumps. ``found``: ``jumps`` of ``ref`` already found (they read every row of the flight);
    None: found now."""
    if found is None:
        found = jumps(np.asarray(ref.position, float), np.asarray(ref.velocity, float), dt)
    at, size = found
    scale = shape * np.sqrt(np.maximum(cable_length, np.linalg.norm(size, axis=-1)) / gravity)
    x = ((rows[:, None] - at + 0.5) * dt) / scale  # (n, m): s from each jump, in its scales
    half = 0.5 * np.exp(-np.abs(x))  # the density x scale
    path = np.where(x < 0, half, 1.0 - half) - (x > 0)  # the CDF less the step itself
    return path @ size, (half / scale) @ size, (-np.sign(x) * half / scale**2) @ size


def reference_ahead(
    ref,
    k: int,
    n: int,
    lean: float = 0.0,
    shape: Shape | None = None,
    found: tuple[np.ndarray, np.ndarray] | None = None,
) -> ReferenceAhead:
    """Rows k+1 .. k+n of a whole flight's reference (``sim.maneuvers.Reference``: position,
    velocity, acceleration (T, 3), yaw (T,)), held at its last row past the end, as the cost
    reads them (``reference_rows``)."""
    idx = np.minimum(np.arange(k + 1, k + n + 1), len(ref.yaw) - 1)
    return reference_rows(ref, idx, lean, shape, found)


def reference_rows(
    ref,
    rows: np.ndarray,
    lean: float = 0.0,
    shape: Shape | None = None,
    found: tuple[np.ndarray, np.ndarray] | None = None,
) -> ReferenceAhead:
    """Rows ``rows`` (n,) of a whole flight's reference: position (n, 3) m, velocity (n, 3)
    m/s, yaw (n,) rad, acceleration (n, 3) m/s^2, float64; the acceleration averaged over
    ``lean`` rows each way (``leaned``; 0: as it is); with a ``shape``, the jumps spread into a
    path (``shaped_jumps``, with its ``found`` jumps; None: as they are). From the whole flight,
    as ``leaned``. A step the vehicle could fly but the hanging load cannot follow becomes a
    path it can: without it the payload cost asks the load to jump on a vertical cable."""
    pos, vel = np.array(ref.position[rows], dtype=float), np.array(ref.velocity[rows], dtype=float)
    acc = leaned(ref.acceleration, rows, lean)
    if shape is not None and shape.factor:
        dp, dv, da = shaped_jumps(ref, rows, *shape, found=found)
        pos, vel, acc = pos + dp, vel + dv, acc + da
    return ReferenceAhead(pos, vel, np.array(ref.yaw[rows], dtype=float), acc)


def yaw_of(q: np.ndarray) -> np.ndarray:
    """Yaw (...,) rad of w-x-y-z quaternions (..., 4)."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def tilt_of(q: np.ndarray) -> np.ndarray:
    """Angle (...,) rad between the body z axis and the world z axis."""
    x, y = q[..., 1], q[..., 2]
    return np.arccos(np.clip(1.0 - 2.0 * (x * x + y * y), -1.0, 1.0))


def trajectory_cost(
    states: np.ndarray,
    plans: np.ndarray,
    ref: ReferenceAhead,
    u_prev: np.ndarray,
    cfg: Any,  # an ``mppi.MPCConfig``
    cable_length: float,
    hover_thrust: float,
    target: VehicleTarget | None = None,
) -> np.ndarray:
    """Cost (K,) of predicted states (K, N, 13) under plans (K, N, 4); u_prev (4,) the input
    applied at the previous step. target: where the vehicle and the cable belong
    (``payload_first``, the "payload" cost); None: the reference itself and a vertical cable
    (the "vehicle" cost). A non-finite prediction gives a non-finite cost."""
    n = states.shape[1]
    step_w = np.ones(n)
    step_w[-1] += cfg.terminal
    p, v, q, pl = states[..., POS], states[..., VEL], states[..., QUAT], states[..., LOAD_POS]
    load_ref = ref.position - np.array([0.0, 0.0, cable_length])
    if target is None:
        p_ref, v_ref, offset = ref.position, ref.velocity, (pl - p)[..., :2]
    else:
        p_ref, v_ref, offset = target.position, target.velocity, (pl - p)[..., :2] - target.offset
    with np.errstate(invalid="ignore", over="ignore"):  # NaN/inf predictions: dropped later
        yaw_err = np.remainder(yaw_of(q) - ref.yaw + math.pi, 2.0 * math.pi) - math.pi
        over_tilt = np.maximum(tilt_of(q) - cfg.max_tilt, 0.0)
        state_cost = (
            cfg.w_position * _huber(_square_norm(p - p_ref), cfg.position_huber)
            + cfg.w_velocity * _square_norm(v - v_ref)
            + cfg.w_load * _huber(_square_norm(pl - load_ref), cfg.position_huber)
            + cfg.w_swing * _square_norm(offset)
            + cfg.w_yaw * np.square(yaw_err)
            + cfg.w_tilt * np.square(over_tilt)
        )  # (K, N)
        if math.isfinite(cfg.max_swing):
            over_swing = np.maximum(frames.swing_angle(states) - cfg.max_swing, 0.0)
            state_cost += cfg.w_swing_bound * np.square(over_swing)
        if math.isfinite(cfg.min_height):
            state_cost += cfg.w_floor * np.square(np.minimum(p[..., 2] - cfg.min_height, 0.0))
    du = np.diff(plans, axis=1, prepend=np.broadcast_to(u_prev, (len(plans), 1, INPUT_DIM)))
    input_cost = (
        cfg.w_thrust * np.square(plans[..., 0] - hover_thrust)
        + cfg.w_rates * _square_norm(plans[..., 1:])
        + cfg.w_thrust_rate * np.square(du[..., 0])
        + cfg.w_rates_rate * _square_norm(du[..., 1:])
    )
    return state_cost @ step_w + input_cost.sum(-1)


def _huber(square: np.ndarray, radius: float) -> np.ndarray:
    """A squared distance (...,) m^2 as is up to ``radius`` m, continued linearly beyond it
    (value and slope continuous); inf radius: unchanged."""
    if not math.isfinite(radius):
        return square
    dist = np.sqrt(square)
    return np.where(dist <= radius, square, radius * (2.0 * dist - radius))


def _square_norm(a: np.ndarray) -> np.ndarray:
    """|a|^2 over the last axis (einsum: faster than square-then-sum for 2-3 columns)."""
    return np.einsum("...d,...d->...", a, a)
