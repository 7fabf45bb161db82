"""In-flight estimates of the load's constants from a history window: the cable length, the load
mass and the thrust gain. Causal (a window's samples only), batched over any leading
dimensions, differentiable, pure torch beside the physics. Measured errors: ``docs/data.md``.

**Cable length**: the mean of |pL - p| over the window. The cable is taut in normal flight and
the noise averages out; what remains is geometry the paper's model does not have (the
attachment below the centre of mass, a tumbling load), a few millimetres.

**Load mass**: the momentum balance across the thrust axis. With b the body z axis, P = I - b b^T
the projection onto the rotor plane and z up, Newton's law for the vehicle and the load,
summed, is ``mQ (a + g e3) + mL (aL + g e3) = kT T b - c P v + F_wake b`` (the cable's tension
cancels; the rotor drag c acts in the rotor plane; the rotor wake pushes the load along b), so

    mL P (aL + g e3) + c P v = -mQ P (a + g e3).

Neither the thrust nor its gain, nor the tension, nor the wake on the load appear: a per-flight
thrust error does not move the estimate. The vehicle mass mQ is taken from the constants (only
the ratio mL / mQ is identifiable: scaling both masses and the thrust leaves the motion
unchanged). Each sample's accelerations are second differences of the positions, its velocity
a central difference, each projected with its own attitude, the drag column scaled by T / mean
T (rotor drag grows with thrust); the projected balance is then smoothed with a triangular
kernel (half-width H = ``config.ESTIMATE_SMOOTHING_STEPS``), which keeps the equation exact (a
sum of exact equations) and divides the differentiated position noise by (H + 1)^2. (mL, c)
is the least-squares solution of the smoothed balance; ``prior_weight`` adds the constants'
``mass_load`` as a prior worth that many (m/s^2)^2 per equation, so a window without swing
falls back to it.

**Thrust gain**: the axial part of the same balance, ``kT T = b . (mQ (a + g e3) + mL (aL + g e3))``
smoothed and fitted through zero with the estimated mL. It is the *effective* gain: the wake's
push on the load counts against the thrust, as it does for the paper's model.

Information comes from the load swinging relative to the thrust axis: a window where the load
hangs still under a hovering vehicle holds none about mL (the load is then one body with the
vehicle), and the attitude noise and a steady wind's drag pull such a window's estimate
towards zero and below. ``pool`` sums the
least-squares sums of several windows (e.g. a flight's) into one estimate.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import torch
from torch import Tensor

from .config import ADAPT_PRIOR_WEIGHT, ADAPT_RANGE, ESTIMATE_SMOOTHING_STEPS, VehicleParams
from .load_state import estimate_load_state
from .physics import VehicleConstants, rollout
from .state import body_z, split_input, split_state

ESTIMATED = ("mass_load", "cable_length")  # what ``WindowConstants.vehicle`` replaces by default
# The least-squares sums of one window, in ``stats``' last dimension (``pool`` adds them up).
G_BB, G_BV, G_VV, M_B, M_V, T_A, T_B, T_T, LENGTH_SUM, COUNT = range(10)


class WindowConstants(NamedTuple):
    """Constants estimated from windows, each (...,) for states (..., M, 13).

    ``rotor_drag`` is the in-plane drag coefficient fitted beside the mass (not a constant of
    the paper's model); ``stats`` (..., 10) the sums they are solved from, for ``pool``.
    """

    cable_length: Tensor  # m, mean |pL - p|
    mass_load: Tensor  # kg
    thrust_gain: Tensor  # -, effective achieved / commanded thrust
    rotor_drag: Tensor  # N/(m/s), in-plane drag at mean thrust
    stats: Tensor  # (..., 10)

    def vehicle(
        self, params: VehicleParams, *, estimated: Sequence[str] = ESTIMATED
    ) -> VehicleConstants:
        """One set of constants per window for ``physics.step`` / ``rollout`` (as
        ``VehicleConstants.stack`` gives): the ``estimated`` ones (of ``mass_load``,
        ``cable_length``, ``thrust_gain``) from here, the rest ``params``', each a tensor
        shaped like the windows' leading dimensions."""
        unknown = set(estimated) - {"mass_load", "cable_length", "thrust_gain"}
        if unknown:
            raise ValueError(f"cannot estimate {sorted(unknown)}")
        like = self.mass_load
        return VehicleConstants(
            *(
                getattr(self, name)
                if name in estimated
                else torch.full_like(like, float(getattr(params, name)))
                for name in VehicleConstants._fields
            )
        )


def estimate_constants(
    states: Tensor,
    inputs: Tensor,
    params: VehicleParams | VehicleConstants,
    *,
    smoothing: int = ESTIMATE_SMOOTHING_STEPS,
    prior_weight: float = 0.0,
) -> WindowConstants:
    """The constants of each window: states (..., M, 13), inputs (..., M, 4) (commanded thrust
    N, body rates), M >= 2 * smoothing + 3 samples ``params.dt`` apart; ``params`` gives dt,
    g, the vehicle mass and (with ``prior_weight`` > 0) the prior load mass. Returns tensors
    (...,) in the states' dtype; gradients reach the states and inputs."""
    if states.shape[-2] < 2 * smoothing + 3:
        raise ValueError(
            f"estimate_constants: a window needs at least 2 * smoothing + 3 = "
            f"{2 * smoothing + 3} steps, got {states.shape[-2]}"
        )
    return _solve(window_stats(states, inputs, params, smoothing, prior_weight))


def adapted(
    states: Tensor,
    inputs: Tensor,
    params: VehicleParams,
    prior_weight: float = ADAPT_PRIOR_WEIGHT,
) -> VehicleConstants:
    """The constants a model adapting to its load runs f with, one set per window: the
    ``params``' with the window's cable length and load mass (``estimate_constants`` with the
    mass prior ``prior_weight``, each clipped to ``ADAPT_RANGE`` times ``params``'). states
    (..., M, 13), inputs (..., M, 4) -> those two as tensors (...,) in the states' dtype, the
    other constants floats; no gradient (the
    estimate is the data's, not the model's)."""
    with torch.no_grad():
        est = estimate_constants(states, inputs, params, prior_weight=prior_weight)
        clipped = {
            name: getattr(est, name).clamp(
                low * getattr(params, name), high * getattr(params, name)
            )
            for name, (low, high) in ADAPT_RANGE.items()
        }
    return VehicleConstants.of(params)._replace(**clipped)  # the others stay floats


def constants_shift(
    states: Tensor,
    inputs: Tensor,
    future_inputs: Tensor,
    params: VehicleParams,
    prior_weight: float = ADAPT_PRIOR_WEIGHT,
) -> Tensor:
    """How far the physics model's prediction moves when it runs with the constants estimated
    from the history (``adapted``) instead of ``params``: (..., N, 13) float64, each rolled out
    from x_{M-1} with its own causal load-state estimate there.

    states (..., M, 13), inputs (..., M, 4): the history (M >= 17); future_inputs (..., N, 4):
    u_M ... u_{M+N-1}, as a window's future (u_{M+N-1} is not used). Members that all learned
    one vehicle's constants agree on another vehicle's motion, so their spread cannot see a
    changed cable or load; this term can (``models.ensemble.Calibration.constants_shift``).
    """
    x, u = states.double(), inputs.double()
    drive = torch.cat([u[..., -1:, :], future_inputs.double()[..., :-1, :]], dim=-2)
    est = adapted(x, u, params, prior_weight)
    # both constant sets in one rollout (a new leading pair): half the steps' overhead
    both = est._replace(**{
        name: torch.stack([value, torch.full_like(value, float(getattr(params, name)))])
        for name, value in zip(est._fields, est, strict=True) if isinstance(value, Tensor)
    })  # fmt: skip
    x2 = x.expand(2, *x.shape)
    aux = estimate_load_state(x2[..., -2:, :], both)[..., -1, :]
    states_both = rollout(x2[..., -1, :], aux, drive.expand(2, *drive.shape), both)[0]
    return states_both[0] - states_both[1]


def pool(estimate: WindowConstants, dim: int | tuple[int, ...] = -1) -> WindowConstants:
    """One estimate from several windows (their least-squares sums added along ``dim`` of the
    leading dimensions), e.g. all windows of a flight."""
    dims = (dim,) if isinstance(dim, int) else dim
    rank = estimate.stats.dim() - 1
    return _solve(estimate.stats.sum(tuple(d % rank for d in dims)))


def window_stats(
    states: Tensor,
    inputs: Tensor,
    params: VehicleParams | VehicleConstants,
    smoothing: int = ESTIMATE_SMOOTHING_STEPS,
    prior_weight: float = 0.0,
) -> Tensor:
    """The least-squares sums (..., 10) of each window (``stats``' layout above)."""
    lateral, axial = _smoothed_balance(states, inputs, params, smoothing)
    load, drag, vehicle = lateral  # (..., K, 3) each
    thrust, axial_vehicle, axial_load = axial  # (..., K) each
    y = -params.mass_quad * vehicle
    prior = prior_weight * 3 * load.shape[-2]  # per equation: 3 components of K samples
    p, _, _, p_load = split_state(states)
    stats = [
        (load * load).sum((-1, -2)) + prior,
        (load * drag).sum((-1, -2)),
        (drag * drag).sum((-1, -2)),
        (load * y).sum((-1, -2)) + prior * params.mass_load,
        (drag * y).sum((-1, -2)),
        (thrust * params.mass_quad * axial_vehicle).sum(-1),
        (thrust * axial_load).sum(-1),
        (thrust * thrust).sum(-1),
        (p_load - p).norm(dim=-1).sum(-1),
        torch.full_like(thrust[..., 0], float(states.shape[-2])),
    ]
    return torch.stack(stats, dim=-1)


def _smoothed_balance(
    states: Tensor, inputs: Tensor, params: VehicleParams | VehicleConstants, smoothing: int
) -> tuple[tuple[Tensor, Tensor, Tensor], tuple[Tensor, Tensor, Tensor]]:
    """The balance's columns at samples 1 .. M-2, smoothed: lateral (P (aL + g e3),
    (T / mean T) P v, P (a + g e3)), each (..., K, 3), and axial (T, b . (a + g e3),
    b . (aL + g e3)), each (..., K), K = M - 2 - 2 * smoothing."""
    h = params.dt
    p, _, q, p_load = split_state(states)
    thrust = split_input(inputs)[0][..., 1:-1]  # (..., M-2)
    b = body_z(q[..., 1:-1, :])  # (..., M-2, 3)
    up = torch.zeros(3, dtype=states.dtype, device=states.device)
    up[2:].fill_(params.gravity)  # a fill on the device: no copy (a CUDA graph allows none)
    acc = (p[..., 2:, :] - 2 * p[..., 1:-1, :] + p[..., :-2, :]) / (h * h) + up
    acc_load = (p_load[..., 2:, :] - 2 * p_load[..., 1:-1, :] + p_load[..., :-2, :]) / (h * h) + up
    vel = (p[..., 2:, :] - p[..., :-2, :]) / (2 * h)
    mean = thrust.mean(-1, keepdim=True).clamp_min(torch.finfo(thrust.dtype).tiny)  # 0: idle
    gain = (thrust / mean).unsqueeze(-1)
    kernel = _triangle(smoothing, states)
    lateral = tuple(
        _smooth(x - (x * b).sum(-1, keepdim=True) * b, kernel) for x in (acc_load, vel * gain, acc)
    )
    axial = (thrust, (acc * b).sum(-1), (acc_load * b).sum(-1))
    smoothed = tuple(_smooth(x.unsqueeze(-1), kernel)[..., 0] for x in axial)
    return lateral, smoothed


def _triangle(half: int, like: Tensor) -> Tensor:
    """Triangular weights (2 half + 1,), summing to 1."""
    j = torch.arange(-half, half + 1, dtype=like.dtype, device=like.device)
    w = half + 1 - j.abs()
    return w / w.sum()


def _smooth(y: Tensor, kernel: Tensor) -> Tensor:
    """(..., K, d) -> (..., K - len(kernel) + 1, d): the kernel's weighted sums along time.
    Shifted slices with constant ends rather than ``unfold``, which ONNX cannot export for a
    window of unknown length."""
    span = len(kernel)
    out = kernel[0] * y[..., : 1 - span, :]
    for j in range(1, span):
        out = out + kernel[j] * y[..., j : (j - span + 1) or None, :]
    return out


def _solve(stats: Tensor) -> WindowConstants:
    """The constants from the sums (..., 10): a 2 x 2 least-squares solve for (mL, c), then kT."""
    g_bb, g_bv, g_vv = stats[..., G_BB], stats[..., G_BV], stats[..., G_VV]
    m_b, m_v = stats[..., M_B], stats[..., M_V]
    tiny = torch.finfo(stats.dtype).eps * (g_bb + g_vv) + torch.finfo(stats.dtype).tiny
    g_vv = g_vv + tiny  # a window without motion: the drag column is zero
    det = g_bb * g_vv - g_bv * g_bv
    mass = (g_vv * m_b - g_bv * m_v) / det
    drag = (g_bb * m_v - g_bv * m_b) / det
    gain = (stats[..., T_A] + mass * stats[..., T_B]) / stats[..., T_T]
    length = stats[..., LENGTH_SUM] / stats[..., COUNT]
    return WindowConstants(length, mass, gain, drag, stats)
