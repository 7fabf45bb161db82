"""A compiled (Numba) copy of ``physics.step`` (the paper's discrete model f, and
``physics.rollout`` of K input sequences from one state) and of the load-state estimates
``load_state.estimate_load_state`` and ``load_state.fit_load_state``; and a numpy copy of
``constants_estimate.adapted`` (``adapted_constants``: a window's constants, once per call).

The model is written once, in batched torch (``physics.py``, ``load_state.py``), where the
loss, training, the eager predictors and the ONNX exports use it. Compiled code cannot call
torch, and a step is a few dozen scalar operations, so the compiled paths carry this copy: the
batch-1 predictor one state per decoder step (``physics_step``), the batched network's decoder
and the physics model's K rollouts candidates in columns (``physics_step_columns``,
``physics_rollout``). One body, ``_step_column``, serves both shapes.

The formulas are the torch functions', in the same form (roma's rotation matrix and quaternion
product, the normalisation floors, the cross products), computed in float64 whatever the arrays'
dtype (a float32 state is rounded once, on the way out). The half rotation angle's sin x / x and
cos x are Taylor polynomials in x^2 (to x^22 / 23!: below 1e-17 relative up to 1 rad, i.e.
|omega| <= 66 rad/s at h = 0.03 s) and the C library's beyond, so that the loop over the
candidates has no call in it and vectorises.

Parity tests: ``tests/test_compiled_physics.py`` holds every function here to its torch
original on random states and inputs (float64: 1e-12, body rates up to 80 rad/s; float32:
1e-5), so a change to ``physics.py`` or ``load_state.py`` that is not made here fails there.
"""

from __future__ import annotations

import math

import numpy as np

from ...config import (
    ADAPT_PRIOR_WEIGHT,
    ADAPT_RANGE,
    ESTIMATE_MIN_STEPS,
    ESTIMATE_SMOOTHING_STEPS,
)
from ...frames import rotation_matrix
from ...layout import (
    AUX_DIM,
    HISTORY_DIM,
    INPUT_DIM,
    LOAD_POS,
    LOAD_RATE,
    LOAD_VEL,
    POS,
    QUAT,
    RATES,
    STATE_DIM,
    THRUST,
    VEL,
)
from ...smoothing import LOAD_FIT_STEPS, load_fit_coefficients
from ...vehicle_constants import VehicleConstants
from .kernels import inline, jit

# Rows of an (x, u) column (the package layout, q w-x-y-z) and of a load state a = (vL, Omega_L).
_P, _V, _Q, _L = POS.start, VEL.start, QUAT.start, LOAD_POS.start
_U = STATE_DIM  # the input's first row
_T, _W = _U + THRUST.start, _U + RATES.start  # thrust, N; body rates, rad/s
_LV, _LR = LOAD_VEL.start, LOAD_RATE.start

# sin(x) / x and cos(x) as polynomials in x^2 (Taylor, to x^22 / 23!), for |x| <= 1 rad.
_SINC = tuple((-1.0) ** n / math.factorial(2 * n + 1) for n in range(12))
_COS = tuple((-1.0) ** n / math.factorial(2 * n) for n in range(12))


@jit
def _poly(coeffs, x2):
    p = coeffs[11]
    for n in range(10, -1, -1):
        p = p * x2 + coeffs[n]
    return p


@inline
def _rotation_poly(r0, r1, r2):
    """exp(r / 2) (w, x, y, z) of the rotation vector r = h omega (rad), for a half angle up to
    1 rad: roma's ``rotvec_to_unitquat`` (cos of the half angle, sinc / 2 times r), by the
    polynomials."""
    x2 = 0.25 * (r0 * r0 + r1 * r1 + r2 * r2)  # (half angle)^2
    s = 0.5 * _poly(_SINC, x2)
    return _poly(_COS, x2), s * r0, s * r1, s * r2


@inline
def _half_angle(r0, r1, r2):
    return 0.5 * math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)


@inline
def _rotation_trig(r0, r1, r2, half):
    """``_rotation_poly`` by the C library's sin and cos (a half angle beyond 1 rad)."""
    s = 0.5 * math.sin(half) / half
    return math.cos(half), s * r0, s * r1, s * r2


@inline
def _rotation_columns(xu, h, dq):
    """dq (4, K) = exp(h omega / 2) (w-x-y-z) of each column's body rates: the polynomials for
    all (one loop without a call), then the C library's for the rare half angles beyond 1 rad."""
    for r in range(xu.shape[1]):
        r0, r1, r2 = h * float(xu[_W, r]), h * float(xu[_W + 1, r]), h * float(xu[_W + 2, r])
        dq[0, r], dq[1, r], dq[2, r], dq[3, r] = _rotation_poly(r0, r1, r2)
    for r in range(xu.shape[1]):
        r0, r1, r2 = h * float(xu[_W, r]), h * float(xu[_W + 1, r]), h * float(xu[_W + 2, r])
        half = _half_angle(r0, r1, r2)
        if half > 1.0:
            dq[0, r], dq[1, r], dq[2, r], dq[3, r] = _rotation_trig(r0, r1, r2, half)


@inline
def _step_column(xu, aux, dq, r, c, x_next, aux_next):
    """``physics.step`` for column r: xu (>= 17, K) = (x_k, u_k), aux (6, K), dq (4, K) the
    rotation increments exp(h omega / 2) (``_rotation_columns``), c ``VehicleConstants`` ->
    column r of x_next (13, K) and aux_next (6, K). ``physics.accelerations`` and
    ``physics.step``'s formulas, float64."""
    mq, ml, length = c.mass_quad, c.mass_load, c.cable_length
    m_sum = mq + ml
    qw, qx = float(xu[_Q, r]), float(xu[_Q + 1, r])
    qy, qz = float(xu[_Q + 2, r]), float(xu[_Q + 3, r])
    inv = 1.0 / max(math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz), 1e-12)
    nw, nx, ny, nz = qw * inv, qx * inv, qy * inv, qz * inv
    thrust = c.thrust_gain * float(xu[_T, r])  # T R e3: roma's third column of R(q / |q|)
    tw0 = 2.0 * (nx * nz + ny * nw) * thrust
    tw1 = 2.0 * (ny * nz - nx * nw) * thrust
    tw2 = (-nx * nx - ny * ny + nz * nz + nw * nw) * thrust
    xi0 = (float(xu[_L, r]) - float(xu[_P, r])) / length
    xi1 = (float(xu[_L + 1, r]) - float(xu[_P + 1, r])) / length
    xi2 = (float(xu[_L + 2, r]) - float(xu[_P + 2, r])) / length
    a0, a1, a2 = float(aux[_LR, r]), float(aux[_LR + 1, r]), float(aux[_LR + 2, r])
    rate_sq = a0 * a0 + a1 * a1 + a2 * a2
    along = xi0 * tw0 + xi1 * tw1 + xi2 * tw2
    t_load = -(ml / m_sum) * along + (ml * mq / m_sum) * length * rate_sq  # the tension
    _axis(xu, aux, x_next, aux_next, r, 0, tw0, xi0, xi1 * tw2 - xi2 * tw1, 0.0, t_load, c)
    _axis(xu, aux, x_next, aux_next, r, 1, tw1, xi1, xi2 * tw0 - xi0 * tw2, 0.0, t_load, c)
    _axis(xu, aux, x_next, aux_next, r, 2, tw2, xi2, xi0 * tw1 - xi1 * tw0, c.gravity, t_load, c)
    dw, dx, dy, dz = dq[0, r], dq[1, r], dq[2, r], dq[3, r]
    w = qw * dw - (qx * dx + qy * dy + qz * dz)  # Hamilton product of the unnormalised q
    a = qw * dx + dw * qx + (qy * dz - qz * dy)
    b = qw * dy + dw * qy + (qz * dx - qx * dz)
    d = qw * dz + dw * qz + (qx * dy - qy * dx)
    inv = 1.0 / max(math.sqrt(w * w + a * a + b * b + d * d), 1e-12)
    x_next[_Q, r], x_next[_Q + 1, r] = w * inv, a * inv
    x_next[_Q + 2, r], x_next[_Q + 3, r] = b * inv, d * inv


@inline
def _axis(xu, aux, x_next, aux_next, r, i, tw, xi, cross, down, t_load, c):
    """Axis i of column r's translational and load-rate updates (``_step_column``)."""
    h, mq, ml = c.dt, c.mass_quad, c.mass_load
    acc = tw / mq - down + (t_load / mq) * xi
    acc_load = -(t_load / ml) * xi - down
    p, v, p_load = float(xu[_P + i, r]), float(xu[_V + i, r]), float(xu[_L + i, r])
    v_load, rate = float(aux[_LV + i, r]), float(aux[_LR + i, r])
    x_next[_P + i, r] = p + h * v + 0.5 * h * h * acc
    x_next[_V + i, r] = v + h * acc
    x_next[_L + i, r] = p_load + h * v_load + 0.5 * h * h * acc_load
    aux_next[_LV + i, r] = v_load + h * acc_load
    aux_next[_LR + i, r] = (1.0 - c.load_damping) * rate + h * (-cross / (mq * c.cable_length))


@jit
def physics_step_columns(xu, aux, c, dq, x_next, aux_next):
    """``physics.step`` for K states in columns: xu (>= 17, K) = (x_k, u_k) (package layout),
    aux (6, K), c ``VehicleConstants`` -> x_next (13, K), aux_next (6, K); dq (4, K) float64
    scratch. Every loop runs over the candidates and vectorises."""
    _rotation_columns(xu, c.dt, dq)
    for r in range(xu.shape[1]):
        _step_column(xu, aux, dq, r, c, x_next, aux_next)


@jit
def physics_step(xu, aux, c, x_next, aux_next):
    """``physics.step`` for one state: xu (>= 17,) = (x_k, u_k) (package layout), aux (6,),
    c ``VehicleConstants`` -> x_next (13,), aux_next (6,); 1-D C-contiguous arrays, any float
    dtype (float64 inside). ``physics_step_columns`` on one column."""
    physics_step_columns(
        xu.reshape((xu.shape[0], 1)), aux.reshape((aux.shape[0], 1)), c, np.empty((4, 1)),
        x_next.reshape((x_next.shape[0], 1)), aux_next.reshape((aux_next.shape[0], 1)),
    )  # fmt: skip


@jit
def physics_rollout(x0, aux0, plans, c, out):
    """``physics.rollout`` of K input sequences from one state, float64: x0 (13,), aux0 (6,),
    plans (K, N, 4) -> out (K, N, 13), each step ``physics_step_columns``."""
    k, n = plans.shape[0], plans.shape[1]
    xu = np.empty((HISTORY_DIM, k))
    aux = np.empty((AUX_DIM, k))
    for j in range(STATE_DIM):
        xu[j] = x0[j]
    for j in range(AUX_DIM):
        aux[j] = aux0[j]
    x_next, aux_next, dq = np.empty((STATE_DIM, k)), np.empty((AUX_DIM, k)), np.empty((4, k))
    for step in range(n):
        for r in range(k):
            for j in range(INPUT_DIM):
                xu[_U + j, r] = plans[r, step, j]
        physics_step_columns(xu, aux, c, dq, x_next, aux_next)
        xu[:STATE_DIM] = x_next
        aux[:] = aux_next
        for j in range(STATE_DIM):
            row = xu[j]
            for r in range(k):
                out[r, step, j] = row[r]


# --- the load state -----------------------------------------------------------------------


@jit
def _swing_rate(last, r_dot, c, aux):
    """aux[Omega_L] = xi x r_dot / l, with xi = r / |r| and r = pL - p of the state ``last``
    (>= 13,); r_dot (3,) m/s. float64 inside."""
    r0 = float(last[_L]) - float(last[_P])
    r1 = float(last[_L + 1]) - float(last[_P + 1])
    r2 = float(last[_L + 2]) - float(last[_P + 2])
    norm = max(math.sqrt(r0 * r0 + r1 * r1 + r2 * r2), 1e-9)
    xi0, xi1, xi2 = r0 / norm, r1 / norm, r2 / norm
    aux[_LR] = (xi1 * r_dot[2] - xi2 * r_dot[1]) / c.cable_length
    aux[_LR + 1] = (xi2 * r_dot[0] - xi0 * r_dot[2]) / c.cable_length
    aux[_LR + 2] = (xi0 * r_dot[1] - xi1 * r_dot[0]) / c.cable_length


@jit
def estimate_load_state(prev, last, c, aux):
    """``load_state.estimate_load_state`` at the later of two consecutive states prev, last
    (>= 13,) -> aux (6,) = (vL m/s, Omega_L rad/s): backward differences of pL and of
    r = pL - p over h, Omega_L = xi x r_dot / l with xi = r / |r|. float64 inside."""
    h = c.dt
    r_dot = np.empty(3)
    for i in range(3):
        aux[_LV + i] = (float(last[_L + i]) - float(prev[_L + i])) / h
        r_dot[i] = (
            (float(last[_L + i]) - float(last[_P + i]))
            - (float(prev[_L + i]) - float(prev[_P + i]))
        ) / h
    _swing_rate(last, r_dot, c, aux)


@jit
def fit_load_state(xu, m, filters, c, aux):
    """``load_state.fit_load_state`` at row m - 1 of xu (M, >= 13) -> aux (6,): the slopes of
    least-squares quadratics through the last K = min(m, rows of filters + 2) rows of pL and
    r = pL - p, weights ``filters[K - 3, :K]`` (``load_filters``); Omega_L = xi x r_dot / l
    with xi from the last row. float64 inside."""
    k = min(m, filters.shape[0] + 2)
    v = np.zeros(3)  # float64 sums, rounded once into aux
    r_dot = np.zeros(3)
    for j in range(k):
        row = xu[m - k + j]
        wgt = filters[k - 3, j]
        for i in range(3):
            v[i] += wgt * float(row[_L + i])
            r_dot[i] += wgt * (float(row[_L + i]) - float(row[_P + i]))
    for i in range(3):
        aux[_LV + i] = v[i]
    _swing_rate(xu[m - 1], r_dot, c, aux)


def load_filters(load_estimate: str, dt: float) -> np.ndarray:
    """``fit_load_state``'s weights for ``load_estimate`` ("smoothed"; anything else: the
    backward difference, an empty (0, 0) table): row K - 3 holds the K weights
    (``smoothing.load_fit_coefficients``) for a window of K = 3 ... LOAD_FIT_STEPS steps."""
    if load_estimate != "smoothed":
        return np.zeros((0, 0), np.float64)
    table = np.zeros((LOAD_FIT_STEPS - 2, LOAD_FIT_STEPS), np.float64)
    for k in range(3, LOAD_FIT_STEPS + 1):
        table[k - 3, :k] = load_fit_coefficients(k, dt)
    return table


def history_constants(
    x_hist: np.ndarray,
    u_past: np.ndarray,
    c: VehicleConstants,
    prior_weight: float = ADAPT_PRIOR_WEIGHT,
) -> VehicleConstants:
    """``adapted_constants`` of a candidate call's history (numpy): x_hist (M, 13), u_past
    (M-1, 4), the inputs applied at all but the last state (whose input the estimate does not
    use)."""
    thrust = np.append(np.asarray(u_past)[:, THRUST.start], 0.0)
    return adapted_constants(x_hist, thrust, c, prior_weight)


def adapted_constants(
    states: np.ndarray,
    thrust: np.ndarray,
    c: VehicleConstants,
    prior_weight: float = ADAPT_PRIOR_WEIGHT,
) -> VehicleConstants:
    """``constants_estimate.adapted`` for one window, numpy float64: states (M, 13) (positions
    relative or absolute), thrust (M,) commanded, N (the last row is not used), the mass prior
    -> ``c`` with the window's cable length and load mass. Once per prediction (every candidate
    of an MPC step shares the history), so numpy rather than a compiled loop."""
    s = np.asarray(states, np.float64)
    h, half = c.dt, ESTIMATE_SMOOTHING_STEPS
    p, p_load = s[:, POS], s[:, LOAD_POS]
    b = rotation_matrix(s[1:-1, QUAT])[..., :, 2]  # body z, (M-2, 3)
    up = np.array([0.0, 0.0, c.gravity])
    acc = (p[2:] - 2 * p[1:-1] + p[:-2]) / (h * h) + up
    acc_load = (p_load[2:] - 2 * p_load[1:-1] + p_load[:-2]) / (h * h) + up
    t = np.asarray(thrust, np.float64)[1:-1]
    vel = (p[2:] - p[:-2]) / (2 * h) * (t / max(t.mean(), np.finfo(np.float64).tiny))[:, None]
    j = np.arange(-half, half + 1, dtype=np.float64)
    kernel = (half + 1 - np.abs(j)) / (half + 1 - np.abs(j)).sum()

    def smoothed(v: np.ndarray) -> np.ndarray:  # (K, 3) projected across b, then smoothed
        v = v - (v * b).sum(-1, keepdims=True) * b
        return sum(kernel[i] * v[i : len(v) - 2 * half + i] for i in range(2 * half + 1))

    load, drag, vehicle = smoothed(acc_load), smoothed(vel), smoothed(acc)
    prior = prior_weight * 3 * len(load)
    target = -c.mass_quad * vehicle
    g_bb, g_bv = (load * load).sum() + prior, (load * drag).sum()
    g_vv = (drag * drag).sum()
    m_b, m_v = (load * target).sum() + prior * c.mass_load, (drag * target).sum()
    g_vv += np.finfo(np.float64).eps * (g_bb + g_vv) + np.finfo(np.float64).tiny
    mass = (g_vv * m_b - g_bv * m_v) / (g_bb * g_vv - g_bv * g_bv)
    length = np.linalg.norm(p_load - p, axis=-1).mean()
    (m_lo, m_hi), (l_lo, l_hi) = ADAPT_RANGE["mass_load"], ADAPT_RANGE["cable_length"]
    return c._replace(
        mass_load=float(np.clip(mass, m_lo * c.mass_load, m_hi * c.mass_load)),
        cable_length=float(np.clip(length, l_lo * c.cable_length, l_hi * c.cable_length)),
    )


def candidates_shift(
    x_hist: np.ndarray,
    u_past: np.ndarray,
    plans: np.ndarray,
    c: VehicleConstants,
    prior_weight: float = ADAPT_PRIOR_WEIGHT,
) -> np.ndarray:
    """``constants_estimate.constants_shift`` of a candidate call, numpy float64: x_hist (M,
    13), u_past (M-1, 4), plans (K, N, 4) u_{M-1} ... u_{M+N-2} -> (K, N, 13), f rolled out
    with the history's ``adapted_constants`` minus with ``c``, each from its own load-state
    estimate at x_{M-1}. M >= ``ESTIMATE_MIN_STEPS`` (the estimate's smoothing)."""
    if len(x_hist) < ESTIMATE_MIN_STEPS:
        raise ValueError(f"the constants shift needs M >= {ESTIMATE_MIN_STEPS} history steps, "
                         f"got {len(x_hist)}")  # fmt: skip
    x = np.ascontiguousarray(x_hist, np.float64)
    drive = np.ascontiguousarray(plans, np.float64)
    out = []
    for constants in (history_constants(x, u_past, c, prior_weight), c):
        aux = np.empty(AUX_DIM)
        estimate_load_state(x[-2], x[-1], constants, aux)
        states = np.empty((*drive.shape[:2], STATE_DIM))
        physics_rollout(x[-1], aux, drive, constants, states)
        out.append(states)
    return out[0] - out[1]
