"""A sampling model-predictive controller (MPPI) for the vehicle and its slung load.

At every control step k (period h = 0.03 s, the data rate) the controller

1. appends the measured state x_k to its history (``history.History``);
2. samples K input sequences u_k ... u_{k+N-1} around its nominal plan (the previous plan
   shifted by one step, its last row repeated): smooth noise (``MPCConfig.knots`` Gaussian
   control points per channel, linearly interpolated over the horizon), **clamped to the
   thrust and body-rate limits**, so every sample, and every convex combination of samples,
   is within them by construction; sample 0 is the nominal plan itself;
3. predicts their N-step outcomes with its ``models.prediction.PredictionModel``
   (``predict_candidates``);
4. scores them (``trajectory_cost``): vehicle position and velocity against the reference
   ahead, load position against its reference (vehicle reference minus l e3), load swing
   (horizontal cable offset), yaw, tilt beyond ``max_tilt``, input effort about hover and
   input rate;
5. weights them by ``exp(-(c - c_min) / lambda)`` with lambda = ``temperature`` times the
   spread ``mean(c) - c_min`` (a scale-free temperature) and applies the first input of the
   weighted plan (receding horizon).

Safe by construction: samples whose prediction is NaN or infinite are dropped; when none is
left, the model raises, or the weighted plan is non-finite or outside the limits, the step
falls back to the last safe plan (shifted), and after ``max_fallback_steps`` consecutive
fallbacks to a hover command (hover thrust, body rates that level the vehicle at its yaw).
Every event is counted in ``MPCStats`` by reason. The MPPI update is written here rather
than taken from ``pytorch-mppi``: see docs/control.md.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from ..config import VehicleParams
from ..models.prediction import PredictionModel
from ..sim.config import SimConfig
from ..sim.controller import Measurement
from ..sim.maneuvers import Reference
from ..state import INPUT_DIM, LOAD_POS, POS, QUAT, STATE_DIM, VEL
from .history import History


@dataclass(frozen=True)
class InputLimits:
    """Box on the commands: thrust N in [thrust_min, thrust_max], |body rate| <= rate_max."""

    thrust_min: float
    thrust_max: float
    rate_max: float  # rad/s, each axis

    @classmethod
    def from_sim(cls, cfg: SimConfig) -> InputLimits:
        """The simulator's limits: thrust up to ``max_thrust``, rates up to ``max_rate`` (the
        PID's own), and at least 30 % of hover thrust (the PID's floor on the vertical force)."""
        return cls(0.3 * cfg.total_mass * cfg.gravity, cfg.max_thrust, cfg.max_rate)

    def lower(self, dtype=torch.float64) -> Tensor:
        return torch.tensor([self.thrust_min] + [-self.rate_max] * 3, dtype=dtype)

    def upper(self, dtype=torch.float64) -> Tensor:
        return torch.tensor([self.thrust_max] + [self.rate_max] * 3, dtype=dtype)

    def contains(self, u: np.ndarray | Tensor, tol: float = 1e-9) -> bool:
        """Every row of u (..., 4) finite and inside the box."""
        u = torch.as_tensor(u, dtype=torch.float64)
        if not bool(torch.isfinite(u).all()):
            return False
        lo, hi = self.lower(), self.upper()
        return bool(((u >= lo - tol) & (u <= hi + tol)).all())

    def at_limit(self, u: np.ndarray, rel: float = 1e-3) -> bool:
        """Whether a command (4,) sits at a bound (within ``rel`` of the range)."""
        thrust_tol = rel * (self.thrust_max - self.thrust_min)
        thrust = u[0] <= self.thrust_min + thrust_tol or u[0] >= self.thrust_max - thrust_tol
        return bool(thrust or (np.abs(u[1:]) >= self.rate_max * (1.0 - rel)).any())


@dataclass(frozen=True)
class MPCConfig:
    """The sampler, the cost weights (per step, SI units squared) and the safety settings."""

    samples: int = 32  # K
    horizon: int = 15  # N, steps of h (0.45 s)
    knots: int = 5  # noise control points per channel over the horizon
    thrust_std: float = 1.0  # N, sampling noise
    rate_std: tuple[float, float, float] = (0.5, 0.5, 0.2)  # rad/s, sampling noise x y z
    temperature: float = 0.3  # lambda / (mean(c) - min(c))
    w_position: float = 20.0  # 1/m^2, vehicle position error
    w_velocity: float = 1.0  # s^2/m^2, vehicle velocity error
    w_load: float = 10.0  # 1/m^2, load position error (reference: vehicle reference - l e3)
    w_swing: float = 10.0  # 1/m^2, horizontal offset of the load from the vehicle
    w_yaw: float = 2.0  # 1/rad^2
    w_tilt: float = 200.0  # 1/rad^2, tilt beyond max_tilt
    max_tilt: float = 0.75  # rad, as the PID's tilt limit
    w_thrust: float = 0.01  # 1/N^2, thrust minus hover thrust
    w_rates: float = 0.05  # s^2/rad^2
    w_thrust_rate: float = 0.05  # 1/N^2, change of thrust per step
    w_rates_rate: float = 0.3  # s^2/rad^2, change of body rates per step
    terminal: float = 5.0  # extra weight of the last step's state terms
    max_fallback_steps: int = 10  # consecutive fallbacks on the last safe plan, then hover
    hover_gain: float = 5.0  # 1/s, attitude error -> body rate of the hover command
    seed: int = 0

    def __post_init__(self) -> None:
        if self.samples < 2 or self.horizon < 2 or not 2 <= self.knots <= self.horizon:
            raise ValueError(
                f"MPCConfig: need samples >= 2, horizon >= 2 and 2 <= knots <= horizon; got "
                f"{self.samples}, {self.horizon}, {self.knots}"
            )
        if not self.temperature > 0:
            raise ValueError(f"MPCConfig.temperature must be > 0, got {self.temperature}")


@dataclass
class MPCStats:
    """What happened over a flight: steps, fallbacks by reason, dropped samples, hover steps."""

    steps: int = 0
    fallbacks: Counter = field(default_factory=Counter)  # reason -> steps
    nonfinite_steps: int = 0  # steps where some (not all) samples predicted NaN/inf
    hover_steps: int = 0  # fallback steps that flew the hover command

    @property
    def fallback_steps(self) -> int:
        return sum(self.fallbacks.values())


def state_from_measurement(m: Measurement) -> np.ndarray:
    """(13,) state x = (p, v, q w-x-y-z, pL) of a ``Measurement``."""
    return np.concatenate([m.p, m.v, m.q_wxyz, m.p_load])


def reference_ahead(ref: Reference, k: int, n: int) -> tuple[Tensor, Tensor, Tensor]:
    """Rows k+1 .. k+n of the reference (held at its last row past the end):
    position (n, 3) m, velocity (n, 3) m/s, yaw (n,) rad, float64."""
    idx = np.minimum(np.arange(k + 1, k + n + 1), len(ref.yaw) - 1)
    return (
        torch.from_numpy(ref.position[idx].copy()),
        torch.from_numpy(ref.velocity[idx].copy()),
        torch.from_numpy(ref.yaw[idx].copy()),
    )


def _yaw(q: Tensor) -> Tensor:
    w, x, y, z = q.unbind(-1)
    return torch.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _tilt(q: Tensor) -> Tensor:
    """Angle between the body z axis and the world z axis, rad."""
    x, y = q[..., 1], q[..., 2]
    return torch.acos((1.0 - 2.0 * (x * x + y * y)).clamp(-1.0, 1.0))


def trajectory_cost(
    states: Tensor,
    plans: Tensor,
    refs: tuple[Tensor, Tensor, Tensor],
    u_prev: Tensor,
    cfg: MPCConfig,
    cable_length: float,
    hover_thrust: float,
) -> Tensor:
    """Cost (K,) of predicted states (K, N, 13) under plans (K, N, 4); refs from
    ``reference_ahead``; u_prev (4,) the input applied at the previous step. A non-finite
    prediction gives a non-finite cost."""
    p_ref, v_ref, yaw_ref = refs
    n = states.shape[1]
    step_w = torch.ones(n, dtype=states.dtype)
    step_w[-1] += cfg.terminal
    p, v, q, pl = states[..., POS], states[..., VEL], states[..., QUAT], states[..., LOAD_POS]
    load_ref = p_ref.clone()
    load_ref[:, 2] -= cable_length
    yaw_err = _yaw(q) - yaw_ref
    yaw_err = torch.atan2(torch.sin(yaw_err), torch.cos(yaw_err))
    over_tilt = (_tilt(q) - cfg.max_tilt).clamp_min(0.0)
    state_cost = (
        cfg.w_position * (p - p_ref).square().sum(-1)
        + cfg.w_velocity * (v - v_ref).square().sum(-1)
        + cfg.w_load * (pl - load_ref).square().sum(-1)
        + cfg.w_swing * (pl - p)[..., :2].square().sum(-1)
        + cfg.w_yaw * yaw_err.square()
        + cfg.w_tilt * over_tilt.square()
    )  # (K, N)
    thrust, rates = plans[..., 0], plans[..., 1:]
    du = torch.diff(plans, dim=1, prepend=u_prev.expand(plans.shape[0], 1, INPUT_DIM))
    input_cost = (
        cfg.w_thrust * (thrust - hover_thrust).square()
        + cfg.w_rates * rates.square().sum(-1)
        + cfg.w_thrust_rate * du[..., 0].square()
        + cfg.w_rates_rate * du[..., 1:].square().sum(-1)
    )
    return (state_cost * step_w).sum(-1) + input_cost.sum(-1)


class SamplingMPC:
    """MPPI controller meeting ``sim.controller.Controller`` (see the module); one per flight.

    model: a ``PredictionModel``; limits: the input box (``InputLimits.from_sim``); params:
    the vehicle constants for hover thrust and cable length (default ``VehicleParams()``).
    ``stats`` counts steps and fallbacks; ``last_plan`` is the plan after the latest step.
    """

    def __init__(
        self,
        model: PredictionModel,
        limits: InputLimits,
        config: MPCConfig | None = None,
        params: VehicleParams | None = None,
    ) -> None:
        self.model = model
        self.limits = limits
        self.cfg = cfg = config or MPCConfig()
        params = params or VehicleParams()
        self.cable_length = params.cable_length
        self.hover_thrust = (params.mass_quad + params.mass_load) * params.gravity
        self.history = History(max(2, model.history))
        self.lo, self.hi = limits.lower(), limits.upper()
        hover = torch.tensor([self.hover_thrust, 0.0, 0.0, 0.0], dtype=torch.float64)
        self.hover = torch.minimum(torch.maximum(hover, self.lo), self.hi)
        self.plan = self.hover.expand(cfg.horizon, INPUT_DIM).clone()  # the last safe plan
        self.u_prev = self.hover.clone()
        self.std = torch.tensor([cfg.thrust_std, *cfg.rate_std], dtype=torch.float64)
        self.interp = _interpolation(cfg.horizon, cfg.knots)  # (N, knots)
        self.gen = torch.Generator().manual_seed(cfg.seed)
        self.stats = MPCStats()
        self._fallback_run = 0

    def __call__(self, measurement: Measurement, reference: Reference, k: int):
        """One control step (the ``Controller`` contract): (thrust N, body rates (3,) rad/s)."""
        self.stats.steps += 1
        self.history.push_state(state_from_measurement(measurement))
        refs = reference_ahead(reference, k, self.cfg.horizon)
        plan, reason = self._optimise(refs)
        if reason is None:
            self._fallback_run = 0
        else:
            plan = self._fallback(reason, measurement, refs)
        u = plan[0]
        self.history.push_input(u.numpy())
        self.u_prev = u.clone()
        self.plan = torch.cat([plan[1:], plan[-1:]], dim=0)  # shifted: the next nominal plan
        return float(u[0]), u[1:].numpy().copy()

    @property
    def last_plan(self) -> Tensor:
        return self.plan

    def sample(self) -> Tensor:
        """K clamped input sequences (K, N, 4) around the nominal plan; row 0 is the plan."""
        cfg = self.cfg
        z = torch.randn(cfg.samples, cfg.knots, INPUT_DIM, generator=self.gen, dtype=torch.float64)
        noise = torch.einsum("nj,kjd->knd", self.interp, z * self.std)
        noise[0] = 0.0
        return torch.minimum(torch.maximum(self.plan + noise, self.lo), self.hi)

    def _optimise(self, refs) -> tuple[Tensor | None, str | None]:
        samples = self.sample()
        m = self.history.m
        x_hist, u_past = self.history.window(self.plan[0].numpy())
        try:
            states = self.model.predict_candidates(x_hist[-m:], u_past[-(m - 1) :], samples)
        except (RuntimeError, ValueError, FloatingPointError) as exc:
            return None, f"prediction error ({type(exc).__name__})"
        if states.shape != (*samples.shape[:2], STATE_DIM):
            return None, "prediction of the wrong shape"
        cost = trajectory_cost(
            states, samples, refs, self.u_prev, self.cfg, self.cable_length, self.hover_thrust
        )
        finite = torch.isfinite(cost) & torch.isfinite(states).flatten(1).all(1)
        if not bool(finite.any()):
            return None, "non-finite prediction"
        if not bool(finite.all()):
            self.stats.nonfinite_steps += 1
        cost = torch.where(finite, cost, torch.full_like(cost, math.inf))
        c_min = cost.min()
        spread = (cost[finite].mean() - c_min).clamp_min(1e-9)
        weights = torch.softmax(-(cost - c_min) / (self.cfg.temperature * spread), dim=0)
        plan = torch.einsum("k,knd->nd", weights, samples)
        if not self.limits.contains(plan):
            return None, "plan outside the limits"
        return plan, None

    def _fallback(self, reason: str, measurement: Measurement, refs) -> Tensor:
        """The last safe plan (already shifted), or hover after too many fallbacks in a row."""
        self.stats.fallbacks[reason] += 1
        self._fallback_run += 1
        if self._fallback_run <= self.cfg.max_fallback_steps and self.limits.contains(self.plan):
            return self.plan
        self.stats.hover_steps += 1
        return self.hover_command(measurement, float(refs[2][0]))

    def hover_command(self, measurement: Measurement, yaw: float) -> Tensor:
        """(N, 4): hover thrust, body rates that level the vehicle at ``yaw``, clamped."""
        rot = np.asarray(measurement.rotation, dtype=float)
        if not np.isfinite(rot).all():
            rates = np.zeros(3)
        else:
            c, s = math.cos(yaw), math.sin(yaw)
            target = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
            err = rot.T @ target  # body frame: rotation from the vehicle to the target
            axis = np.array([err[2, 1] - err[1, 2], err[0, 2] - err[2, 0], err[1, 0] - err[0, 1]])
            rates = 0.5 * self.cfg.hover_gain * axis  # small-angle rotation vector times gain
        u = torch.tensor([self.hover_thrust, *rates], dtype=torch.float64)
        u = torch.minimum(torch.maximum(u, self.lo), self.hi)
        plan = self.hover.expand(self.cfg.horizon, INPUT_DIM).clone()
        plan[0] = u
        return plan


def _interpolation(n: int, knots: int) -> Tensor:
    """(n, knots) linear interpolation from knots evenly spread over steps 0 .. n-1."""
    at = torch.linspace(0.0, knots - 1.0, n, dtype=torch.float64)
    return (1.0 - (at[:, None] - torch.arange(knots, dtype=torch.float64)).abs()).clamp_min(0.0)
